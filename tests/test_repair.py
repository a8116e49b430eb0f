"""The level repair of learned allocators (farm.alloc.allocators.repair): hand-made states whose
repaired games are worked out by hand, the invariants on random actions (every cell keeps its
mass, no target's game shrinks, no count rises by more than the tolerance), receding_horizon's
actions left as they are, and the settings that choose it."""

import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from farm.alloc import AllocConfig
from farm.alloc.game.dynamics import Layout, move_probabilities
from farm.alloc.game.model import advance_intruders, team_sizes
from farm.alloc.allocators import make_allocator
from farm.alloc.allocators.planners import action_from_probabilities
from farm.alloc.allocators.repair import REL, TOL, LevelRepair, Repaired, RepairedActions
from farm.alloc.game.scenarios import SCENARIOS
from farm.alloc.training import TrainConfig
from farm.core.errors import ConfigError

from conftest import farm_main
from test_learners import assert_refused_in_one_line, client, config  # noqa: F401 (fixtures)
from test_planners import curve_client

PAPER = AllocConfig(grid_size=3, n_defenders=100, n_intruders=50, c_capture=1.5, team_sizes="lattice")
FEW = AllocConfig(grid_size=3, n_defenders=4, n_intruders=100, c_capture=1.5, team_sizes="lattice")
DRIFT = AllocConfig(grid_size=5, n_defenders=20, n_intruders=100, vertical_drift=0.25, max_steps=16,
                    c_capture=1.5, team_sizes="lattice")


def base_state(config, rows):
    """obs [D, I]: every defender at the base (row N//2, col 0), the intruders' row shares in the right column."""
    n = config.grid_size
    D, I = np.zeros(n * n), np.zeros(n * n)
    D[(n // 2) * n] = 1.0
    I[np.arange(n) * n + n - 1] = rows
    return np.concatenate([D, I]).astype(np.float32)


def action_sending(config, obs, wanted: dict) -> np.ndarray:
    """The action that sends the base's defenders to {cell: share} (the planners' own map back)."""
    L = Layout(config.grid_size)
    base = (config.grid_size // 2) * config.grid_size
    p = np.zeros(len(L.src))
    for s in range(L.cells):  # every other cell stays
        p[L.start[s] + list(L.dst[L.start[s]:L.start[s] + L.n_moves[s]]).index(s)] = 1.0
    sl = slice(L.start[base], L.start[base] + L.n_moves[base])
    p[sl] = 0.0
    for cell, share in wanted.items():
        p[L.start[base] + list(L.dst[sl]).index(cell)] = share
    return action_from_probabilities(config, p, L.start, L.src)


def realised(config, obs, action):
    """(p: (A,) the realised move probabilities, x: (N^2,) counts after the move, n_p: (N^2,) their
    games' defenders at the cells holding intruders after the advance (0 elsewhere))."""
    L = Layout(config.grid_size)
    k = L.cells
    p = move_probabilities(L, config, np.asarray(action, dtype=np.float64)[None])[0]
    x = np.bincount(L.dst, weights=p * obs[:k].astype(np.float64)[L.src], minlength=k)
    I2, _ = advance_intruders(obs[k:].astype(np.float64), config.grid_size, config.vertical_drift)
    n_p, _ = team_sizes(config, x, np.maximum(I2, 1e-3))
    return p, x * config.n_defenders, np.where(I2 > config.engage_min_mass, n_p, 0)


@pytest.mark.parametrize("spare", [3, 0])
def test_a_target_just_short_of_a_level_is_filled_from_free_defenders(spare):
    # 27.3 defenders round to 27, which snaps to 24 (32's window starts at 27.6); the other row's
    # 60 play 64 (its window from 55.6, 96's from 78.6, too far to fill); 12.7 go to a cell no
    # intruder comes to (staying at the base, or the corner), the first free defenders in the
    # base's moves
    obs = base_state(PAPER, [0.35, 0.2, 0.45])
    action = action_sending(PAPER, obs, {1: 0.273, 7: 0.6, spare: 0.127})
    _, x0, n0 = realised(PAPER, obs, action)
    assert n0[1] == 24 and n0[7] == 64
    _, x, n_p = realised(PAPER, obs, LevelRepair(PAPER)(obs, action))
    assert n_p[1] == 32 and n_p[7] == 64
    assert 27.6 <= x[1] <= 27.7 and x.sum() == pytest.approx(100.0, abs=1e-9)
    assert x[spare] == pytest.approx(x0[spare] - (x[1] - x0[1]), abs=0.05) and x[7] == pytest.approx(x0[7], abs=0.05)


def test_no_target_near_a_threshold_leaves_the_moves_as_they_were():
    obs = base_state(PAPER, [0.35, 0.2, 0.45])
    action = action_sending(PAPER, obs, {1: 0.40, 7: 0.60})  # 48's window from 39.6, 64's from 55.6
    repaired = LevelRepair(PAPER)(obs, action)
    np.testing.assert_array_equal(realised(PAPER, obs, repaired)[0], realised(PAPER, obs, action)[0])


def test_a_target_that_cannot_be_filled_whole_is_left_and_no_game_shrinks():
    # 4 defenders: 1.8 and 2.2 play 2 each; 2.2 is 0.4 short of 3 (2.6), but the only free
    # defenders are the 0.2 of the other row above its window's low end (1.6)
    obs = base_state(FEW, [0.35, 0.2, 0.45])
    action = action_sending(FEW, obs, {1: 0.45, 7: 0.55})
    repaired = LevelRepair(FEW)(obs, action)
    np.testing.assert_array_equal(realised(FEW, obs, repaired)[0], realised(FEW, obs, action)[0])
    assert list(realised(FEW, obs, repaired)[2][[1, 7]]) == [2, 2]


def test_defenders_that_play_no_game_fill_a_target():
    # 4 defenders: 2.2 towards row 2's intruders (2 plays), 1.8 stay at the base, where no intruder comes
    obs = base_state(FEW, [0.35, 0.2, 0.45])
    action = action_sending(FEW, obs, {7: 0.55, 3: 0.45})
    _, x, n_p = realised(FEW, obs, LevelRepair(FEW)(obs, action))
    assert n_p[7] == 3 and 2.6 <= x[7] <= 2.7


@settings(max_examples=40, deadline=None, derandomize=True)
@given(which=st.sampled_from([0, 1, 2]), seed=st.integers(0, 2**31 - 1))
def test_random_actions_keep_every_cells_mass_shrink_no_game_and_move_within_the_tolerance(which, seed):
    config = (PAPER, FEW, DRIFT)[which]
    rng = np.random.default_rng(seed)
    L = Layout(config.grid_size)
    k = L.cells
    D = rng.dirichlet(np.full(k, 0.3))
    I = rng.dirichlet(np.full(k, 0.3)) * rng.uniform(0.2, 1.0)
    obs = np.concatenate([D, I]).astype(np.float32)
    action = rng.uniform(-1, 1, len(L.src)).astype(np.float32)
    p0, x0, n0 = realised(config, obs, action)
    p, x, n_p = realised(config, obs, LevelRepair(config)(obs, action))
    np.testing.assert_allclose(np.add.reduceat(p, L.start), 1.0, atol=1e-12)  # every cell's mass goes somewhere
    assert np.all(n_p >= n0)  # no target's game gets smaller
    leak = 0.01 * config.n_defenders * 8 * np.exp(-2 * config.softmax_beta) + 1e-6
    assert np.all(x - x0 <= np.maximum(TOL, REL * x) + leak)  # no count rises by more than the tolerance


def plain_repair(repair: LevelRepair, obs, action) -> np.ndarray:
    """The repair's fill written plainly (the module doc, step by step): every target in order of
    intruder mass, each checked against the next window at its count then, and every move of every
    neighbour looked at. LevelRepair skips the targets that cannot be near a threshold."""
    L, lo, config = repair.layout, repair.levels.lo, repair.config
    p, f, x, target, I2 = repair.flows(obs, action)
    free = np.where(target, x - repair.floors(x), x)
    changed = False
    for d in np.argsort(-I2, kind="stable"):
        if not target[d]:
            break
        i = int(np.searchsorted(lo, x[d], side="right"))
        if i >= len(lo) or lo[i] - x[d] + 1e-9 > max(repair.tol, repair.rel * lo[i]):
            continue
        need, takes, got = lo[i] - x[d] + 1e-9, [], 0.0
        for m_in in np.flatnonzero(L.dst == d):
            s = L.src[m_in]
            for m in range(L.start[s], L.start[s] + L.n_moves[s]):
                e = L.dst[m]
                if e == d or f[m] <= 0.0:
                    continue
                amount = min(f[m], free[e], need - got)
                if amount > 0.0:
                    takes.append((m, e, m_in, amount))
                    free[e] -= amount
                    got += amount
                if got >= need:
                    break
            if got >= need:
                break
        if got < need:
            for _, e, _, amount in takes:
                free[e] += amount
            continue
        for m, e, m_in, amount in takes:
            f[m], x[e], f[m_in], x[d] = f[m] - amount, x[e] - amount, f[m_in] + amount, x[d] + amount
        free[d], changed = 0.0, True
    if not changed:
        return np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0).astype(np.float32)
    total = np.add.reduceat(f, L.start)[L.src]
    q = np.where(total > 0.0, f / np.where(total > 0.0, total, 1.0), p)
    return action_from_probabilities(config, q, L.start, L.src)


def test_the_repair_equals_its_plain_loop_over_every_target():
    theatre = SCENARIOS["theatre_16x16"].config()
    exact = AllocConfig(grid_size=5, n_defenders=100, n_intruders=50, c_capture=1.5, team_sizes="exact", max_steps=16)
    rng = np.random.default_rng(7)
    repaired_states = 0
    for map_config in (PAPER, FEW, DRIFT, exact, theatre):
        repair, L = LevelRepair(map_config), Layout(map_config.grid_size)
        for _ in range(40):
            spread = rng.choice([0.05, 0.3, 3.0])
            D = rng.dirichlet(np.full(L.cells, spread))
            I = rng.dirichlet(np.full(L.cells, spread)) * rng.uniform(0.2, 1.0)
            I[rng.random(L.cells) < 0.3] = 0.0
            obs = np.concatenate([D, I]).astype(np.float32)
            action = rng.uniform(-1, 1, len(L.src)).astype(np.float32)
            expected = plain_repair(repair, obs, action)
            np.testing.assert_array_equal(repair(obs, action), expected)
            repaired_states += not np.array_equal(expected, np.clip(action, -1, 1))
    assert repaired_states >= 100  # most of the 200 states had a target filled


def test_receding_horizons_actions_play_the_same_games_repaired():
    curves = curve_client(PAPER)
    planner = make_allocator("receding_horizon", PAPER, curves)
    repair = LevelRepair(PAPER)
    rng = np.random.default_rng(5)
    for _ in range(6):
        obs = base_state(PAPER, rng.dirichlet(np.ones(3)))
        action, _ = planner.predict(obs)
        np.testing.assert_array_equal(realised(PAPER, obs, repair(obs, action))[2], realised(PAPER, obs, action)[2])


class Fixed:
    """An allocator that answers every observation with one action."""

    def __init__(self, action, n: int = 3):
        import gymnasium

        self.action = action
        self.observation_space = gymnasium.spaces.Box(0.0, 1.0, (2 * n * n,))

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return self.action, state


def test_a_runs_repair_setting_makes_its_allocator_repaired(tmp_path):
    obs = base_state(PAPER, [0.35, 0.2, 0.45])
    network = Fixed(action_sending(PAPER, obs, {1: 0.273, 7: 0.6, 3: 0.127}))
    (tmp_path / "config.yaml").write_text(yaml.safe_dump({"name": "x", "algo": "ppo", "repair": "levels"}))
    allocator = make_allocator("ppo", PAPER, None, policy=network, run=str(tmp_path))
    assert isinstance(allocator, Repaired) and realised(PAPER, obs, allocator.predict(obs)[0])[2][1] == 32
    assert make_allocator("ppo", PAPER, None, policy=network, run=str(tmp_path), repair="none") is network
    (tmp_path / "config.yaml").write_text(yaml.safe_dump({"name": "x", "algo": "ppo"}))  # a run from before it
    assert make_allocator("ppo", PAPER, None, policy=network, run=str(tmp_path)) is network


def test_the_evaluation_env_of_a_repaired_run_plays_the_repaired_action():
    from farm.alloc import SwarmAllocationEnv

    env = RepairedActions(SwarmAllocationEnv(PAPER, client=curve_client(PAPER)))
    obs, _ = env.reset(seed=3)
    action = action_sending(PAPER, obs, {1: 0.273, 7: 0.6, 3: 0.127})
    wanted = LevelRepair(PAPER)(obs, action)
    inner = env.unwrapped
    D, I = obs[:9].astype(np.float64), obs[9:].astype(np.float64)
    env.step(action)
    L = Layout(3)
    moved = np.bincount(L.dst, weights=move_probabilities(L, PAPER, wanted[None].astype(np.float64))[0] * D[L.src],
                        minlength=9)
    np.testing.assert_allclose(inner.D, moved, atol=1e-12)
    assert I.sum() > 0


def test_bad_repair_settings_are_one_line(tmp_path):
    with pytest.raises(ConfigError, match=r"^repair: must be one of none, levels, got 'round'$"):
        make_allocator("ppo", PAPER, None, policy=Fixed(None), repair="round")
    with pytest.raises(Exception, match="repair"):
        TrainConfig(name="x", algo="ppo", repair="round")
    assert_refused_in_one_line(tmp_path, {"name": "x", "algo": "ppo", "repair": "round"}, "repair")


def test_a_repaired_run_evaluates_repaired_and_acts_repaired(store, client, tmp_path):  # noqa: F811
    # its resume, bit-identical: test_learners' batched-env resume test, repair levels
    from farm.alloc.training import train
    from farm.alloc.training.train import _eval_envs

    cfg = config(store, "ppo", n_envs=4, repair="levels")
    eval_vec, _ = _eval_envs(cfg, client)
    assert isinstance(eval_vec.venv.envs[0], RepairedActions)  # the periodic evaluations act repaired
    cfg = cfg.model_copy(update={"n_envs": 1})
    eval_monitor, _ = _eval_envs(cfg, client)
    assert isinstance(eval_monitor.env, RepairedActions)
    train(config(store, "ppo", n_envs=4, repair="levels", ppo={"n_timesteps": 128, "n_steps": 32, "batch_size": 32,
                                                               "n_epochs": 1}), tmp_path / "run", show_progress=False)
    assert isinstance(make_allocator("ppo", cfg.env, None, run=str(tmp_path / "run")), Repaired)
    # farm eval acts as the run says, or as --repair says: the network alone is its own episodes
    from farm.alloc.evaluation.evaluate import evaluate_run
    from farm.alloc.evaluation.rollout import play

    def learned_return(table):
        return float(table.loc[table["policy"] == "ppo", "return_mean"].iloc[0])

    as_run = evaluate_run(tmp_path / "run", episodes=2, references=[], show_progress=False)
    repaired_eval = evaluate_run(tmp_path / "run", episodes=2, references=[], show_progress=False, repair="levels")
    alone = evaluate_run(tmp_path / "run", episodes=2, references=[], show_progress=False, repair="none")
    assert learned_return(as_run.table) == learned_return(repaired_eval.table)
    assert as_run.folder == repaired_eval.folder == tmp_path / "run"  # the run's own: its folder
    assert alone.folder == tmp_path / "run" / "repair_none"  # another: its own, the run's evaluation kept
    kept = pd.read_csv(tmp_path / "run" / "eval_table.csv")
    kept_return = float(kept.loc[kept["policy"] == "ppo", "return_mean"].iloc[0])
    assert kept_return == pytest.approx(learned_return(as_run.table))
    assert (alone.folder / "eval_table.csv").is_file()
    for repair, result in (("levels", repaired_eval), ("none", alone)):
        policy = make_allocator("ppo", cfg.env, None, run=str(tmp_path / "run"), repair=repair)
        episodes = play(cfg.env, policy, client, 2, 1000)
        assert learned_return(result.table) == pytest.approx(np.mean([e.summary["return"] for e in episodes]),
                                                             abs=1e-12)
    status, _, stderr = farm_main("eval", tmp_path / "run", "--episodes", "1", "--repair", "round")
    assert status != 0 and stderr.strip() == "farm: error: --repair: must be one of none, levels, got 'round'", stderr
