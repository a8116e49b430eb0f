"""The size-independent learner: CellPolicy's weights act on a map of any size.

- A model trained on the 8 x 8 theatre (configs/train/tiny_size_free.yaml) loads and acts on
  other maps with the same weights; `farm eval RUN --scenario NAME` evaluates it there.
- The moves off the map are masked: no score of one reaches the action.
- A policy whose size is its map's (an MLP) is refused on another map in one line.
- The live engagements' coarse tasks (farm.alloc.evaluation.fidelity.pack_games).
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
import yaml

from farm.alloc.game.dynamics import moves, n_actions
from farm.alloc.evaluation.fidelity import pack_games
from farm.alloc.game.scenarios import SCENARIOS
from farm.alloc.training import load_train_config, train

from conftest import train_tiny_run
from helpers import farm_in_repo as farm

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """configs/train/tiny_size_free.yaml trained (256 PPO steps on theatre_8x8), on a store of its own."""
    tmp = tmp_path_factory.mktemp("size_free")
    config = load_train_config(REPO / "configs" / "train" / "tiny_size_free.yaml")
    config = config.model_copy(update={"service": config.service.model_copy(update={"store": str(tmp / "s.sqlite")})})
    train(config, tmp / "run", show_progress=False)
    return tmp / "run"


@pytest.mark.slow
def test_a_model_trained_on_one_map_acts_on_others_with_the_same_weights(run):
    from farm.alloc.allocators import make_allocator
    from farm.alloc.allocators.learned import load_model
    from farm.alloc.networks.cell_policy import resized

    trained = load_model(run, "ppo").policy
    assert trained.grid == 8 and trained.teams == (6, 400)
    own = SCENARIOS["theatre_8x8"].config(games=3)
    assert resized(trained, own) is trained
    rng = np.random.default_rng(0)
    for name in ("theatre_16x16", "theatre_32x32", "paper_3x3_c1_0"):
        config = SCENARIOS[name].config()
        policy = make_allocator("ppo", config, None, run=run)  # the registry's learned allocator, on that map
        n = config.grid_size
        assert policy.grid == n and policy.teams == (config.n_defenders, config.n_intruders)
        same = {k: v for k, v in trained.state_dict().items() if k != "log_std"}
        for key, value in same.items():
            assert torch.equal(policy.state_dict()[key], value), key
        assert policy.log_std.shape == (n_actions(n),)
        assert torch.allclose(policy.log_std, trained.log_std.mean().expand(n_actions(n)))
        obs = rng.uniform(0, 0.05, 2 * n * n).astype(np.float32)
        action, _ = policy.predict(obs, deterministic=True)
        assert action.shape == (n_actions(n),) and np.all(np.abs(action) <= 1)
        again, _ = policy.predict(obs, deterministic=True)
        np.testing.assert_array_equal(action, again)


@pytest.mark.slow
def test_the_moves_off_the_map_are_never_in_the_action(run):
    from farm.alloc.allocators.learned import load_model
    from farm.alloc.networks.cell_policy import resized

    policy = resized(load_model(run, "ppo").policy, SCENARIOS["theatre_16x16"].config())
    net, n = policy.mlp_extractor, 16
    src, dst, _ = moves(n)
    obs = torch.as_tensor(np.random.default_rng(1).uniform(0, 0.05, (3, 2 * n * n)), dtype=torch.float32)
    with torch.no_grad():
        features = net.actor(obs, net.geometry)
        scores = net.scores(features)  # (3, 9, n, n): every direction of every cell
        rows, cols = np.divmod(np.arange(n * n), n)
        off = np.zeros((9, n * n), dtype=bool)
        for k in range(9):
            r, c = rows + k // 3 - 1, cols + k % 3 - 1
            off[k] = (r < 0) | (r >= n) | (c < 0) | (c >= n)
        assert off.sum() == 9 * n * n - n_actions(n)
        flat = scores.flatten(1).clone()
        action = flat[:, net.index]
        flat[:, torch.as_tensor(off.reshape(-1))] = 1e6  # off-map scores changed beyond any range
        np.testing.assert_array_equal(flat[:, net.index].numpy(), action.numpy())
        np.testing.assert_array_equal(net.forward_actor(obs).numpy(), action.numpy())
    assert not off.reshape(-1)[net.index.numpy()].any()


@pytest.mark.slow
def test_farm_eval_scenario_evaluates_the_run_on_another_map(run):
    r = farm("eval", run, "--scenario", "theatre_16x16", "--episodes", 1, "--references", "intercept,receding_horizon")
    assert r.returncode == 0, r.stderr
    table = pd.read_csv(run / "scenarios" / "theatre_16x16" / "eval_table.csv")
    assert list(table["policy"]) == ["ppo", "intercept", "receding_horizon"]
    assert (table["length_mean"] == 16).all()
    assert not (run / "eval_table.csv").exists()  # the run's own evaluation is another folder's
    r = farm("eval", run, "--scenario", "theatre_16x16", "--references", "ppo")
    assert r.returncode != 0 and r.stderr.startswith("farm: error: --references: 'ppo' is not a baseline or planner")
    r = farm("eval", run, "--scenario", "theatre_64x64")
    assert r.returncode != 0
    assert r.stderr.strip().startswith("farm: error: --scenario: unknown scenario 'theatre_64x64'")
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_policy_whose_size_is_its_maps_is_refused_on_another_map(tmp_path):
    mlp = train_tiny_run(tmp_path)  # an MLP's input is its map's size: 3x3
    r = farm("eval", mlp, "--scenario", "theatre_16x16")
    assert r.returncode != 0 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith("farm: error: --scenario: the model was trained on a 3x3 map")
    assert "CellPolicy" in r.stderr


@pytest.mark.parametrize("costs, target", [([0.1] * 12, 0.5), ([0.6, 0.1, 0.2, 0.3, 2.0, 0.01], 0.5), ([0.2], 0.5),
                                           ([], 0.5)])
def test_games_are_packed_into_tasks_of_about_the_target(costs, target):
    tasks = pack_games(costs, target)
    assert [k for t in tasks for k in t] == list(range(len(costs)))  # every game once, in order
    sums = [sum(costs[k] for k in t) for t in tasks]
    assert all(s >= target for s in sums[:-1])  # each task but the last reaches the target
    assert all(s - costs[t[-1]] < target for s, t in zip(sums, tasks))  # and closes as soon as it does


@pytest.mark.slow
def test_a_curriculum_of_maps_labels_every_map_and_resumes_bit_identical(tmp_path, monkeypatch):
    from farm.alloc.training.dagger import loop as pretrain_module
    from farm.alloc.training.dagger.iterations import read_iteration
    from helpers import Stop, assert_same_policy

    raw = yaml.safe_load((REPO / "configs" / "train" / "tiny_size_free.yaml").read_text())
    raw["service"]["store"] = str(tmp_path / "s.sqlite")
    raw["pretrain"] = {"expert": "intercept", "iterations": 2, "episodes": 2, "epochs": 2, "episodes_per_task": 2,
                       "maps": ["outnumbered_3x3", "theatre_16x16"]}
    from farm.alloc.training import TrainConfig

    cfg = TrainConfig(**raw)
    whole = train(cfg, tmp_path / "whole", show_progress=False)
    state = read_iteration(pretrain_module.iteration_file(tmp_path / "whole", 1))
    sizes = [d["obs"].shape[1] for d in state["data"]]
    assert sizes == [2 * 8 * 8, 2 * 3 * 3, 2 * 16 * 16]  # the run's map first, then the curriculum's
    assert all(len(d["obs"]) == len(d["labels"]) > 0 for d in state["data"])
    assert whole["pretrain_states"] == sum(len(d["obs"]) for d in state["data"])
    real, calls = pretrain_module.label_all, []

    def stop_in_iteration_2(*args, **kwargs):
        calls.append(1)
        if len(calls) == 4:  # iteration 1's first map
            raise Stop()
        return real(*args, **kwargs)

    monkeypatch.setattr(pretrain_module, "label_all", stop_in_iteration_2)
    with pytest.raises(Stop):
        train(cfg, tmp_path / "stopped", show_progress=False)
    monkeypatch.setattr(pretrain_module, "label_all", real)
    train(cfg, tmp_path / "stopped", resume=True, show_progress=False)
    assert_same_policy(tmp_path / "whole" / "model.zip", tmp_path / "stopped" / "model.zip", "ppo")


def test_a_curriculum_needs_a_policy_that_fits_any_map(tmp_path):
    from test_learners import assert_refused_in_one_line

    raw = yaml.safe_load((REPO / "configs" / "train" / "tiny.yaml").read_text())
    raw["algo"] = "ppo"
    raw["ppo"] = {"n_timesteps": 256}
    raw["pretrain"] = {"expert": "intercept", "maps": ["theatre_16x16"]}
    assert_refused_in_one_line(tmp_path, raw, "pretrain.maps")
    raw["ppo"] = {"n_timesteps": 256, "policy": "CellPolicy"}
    raw["pretrain"] = {"expert": "intercept", "maps": ["theatre_64x64"]}
    assert_refused_in_one_line(tmp_path, raw, "pretrain.maps")


def test_a_small_step_is_split_over_the_cpus_and_a_large_one_in_half_second_tasks():
    from farm.alloc.evaluation.fidelity import MIN_TASK_SECONDS, TASK_SECONDS, TASKS_PER_CPU, task_seconds

    assert task_seconds(100.0, 2) == TASK_SECONDS
    assert task_seconds(0.8, 2) == pytest.approx(0.8 / (TASKS_PER_CPU * 2))  # TASKS_PER_CPU tasks a CPU
    assert task_seconds(0.01, 2) == MIN_TASK_SECONDS


def test_under_the_games_fidelity_every_engagement_is_a_game_of_its_own(tmp_path):
    """A step with more engagements than the model deduplicates from (70 of one team-size pair)
    plays 70 games, the case's next fresh ones in order, not one game for all 70."""
    from farm.alloc.evaluation.fidelity import FreshGames
    from farm.alloc.game.model import EngagementModel
    from farm.service import CaptureTimeClient
    from workers import run_games

    config = SCENARIOS["outnumbered_3x3"].config(games=2)
    service = CaptureTimeClient(config.game_settings(), local_store=tmp_path / "s.sqlite")
    games = FreshGames(service, in_process=True)
    model = EngagementModel(config, CaptureTimeClient(config.game_settings(), backend=games))
    removed, _, _ = model.lookup(np.full(70, 2), np.full(70, 3))
    assert games.games == 70 and [d["game"] for d in games.differences] == list(range(2, 72))
    key = config.game_settings().key(2, 3)
    captured = run_games(key.case, key.seed, 2, 72).capture_times <= config.tau  # (70, 3): each game's evaders
    np.testing.assert_allclose(removed, captured.mean(axis=1))
    assert len(np.unique(removed)) > 1  # 70 games, not one answer repeated
    service.close()


def test_the_games_fidelity_shows_its_steps_and_games_per_second(tmp_path, capsys):
    """evaluate_fidelity's bar counts the policies' steps (max_steps each, the steps of episodes
    that ended early included at a policy's end) and shows the games played and their games/s,
    the same count as the returned live summary's."""
    from farm.alloc.evaluation.fidelity import evaluate_fidelity
    from farm.alloc.allocators import make_allocator
    from farm.service import CaptureTimeClient

    config = SCENARIOS["outnumbered_3x3"].config(games=2, max_steps=4)
    client = CaptureTimeClient(config.game_settings(), local_store=tmp_path / "s.sqlite")
    policies = {p: make_allocator(p, config, client) for p in ("intercept", "spread_evenly")}
    _, differences, live = evaluate_fidelity(config, policies, client, 2, 1000, in_process=True)
    last = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert last.startswith("live engagements: 100%") and "8/8" in last, last
    assert f"games={live['games']:,}" in last and "games_per_s=" in last, last
    assert live["games"] == len(differences) > 0
    _, _, quiet = evaluate_fidelity(config, policies, client, 2, 1000, in_process=True, show_progress=False)
    assert capsys.readouterr().err == "" and quiet["games"] == live["games"]
    client.close()


def test_lateral_summaries_tell_left_from_right_in_a_row_beyond_the_convolutions():
    """Three 3 x 3 layers see 3 cells to each side. On a 24 x 24 map, intruders 6 cells left of
    cell (12, 12) and intruders 5 cells right of it are beyond what it sees, and the cells they
    reach are beyond the edges' reach (the convolutions are translation-equivariant there):
    without `lateral` they reach its features only through the row's maximum, the same
    features to the bit; with it through the left and right maxima too, and differently."""
    from farm.alloc.networks.cell_policy import CellNet

    n = 24

    def features(lateral: bool, column: int) -> torch.Tensor:
        torch.manual_seed(0)
        net = CellNet(n, 8, 3, teams=(10, 5), positions=False, lateral=lateral)
        obs = torch.zeros(1, 2 * n * n)
        obs[0, n * n + 12 * n + column] = 0.4  # intruders at (12, column)
        with torch.no_grad():
            return net.actor(obs, net.geometry)[0, :, 12, 12]

    assert torch.equal(features(False, 6), features(False, 17))
    assert not torch.allclose(features(True, 6), features(True, 17), atol=1e-6)


def test_a_lateral_policy_keeps_its_weights_and_option_on_another_map():
    import gymnasium as gym

    from farm.alloc.networks.cell_policy import CellPolicy, resized

    n = 4
    policy = CellPolicy(gym.spaces.Box(0.0, 1.0, (2 * n * n,), np.float32),
                        gym.spaces.Box(-1.0, 1.0, (n_actions(n),), np.float32), lambda _: 1e-3, channels=8, layers=2,
                        teams=(10, 5), lateral=True)
    config = SCENARIOS["theatre_16x16"].config()
    other = resized(policy, config)
    assert other.lateral and other.grid == 16
    mine = {k: v for k, v in policy.state_dict().items() if k != "log_std"}
    assert any(".left." in k for k in mine) and all(torch.equal(other.state_dict()[k], v) for k, v in mine.items())
    action, _ = other.predict(np.full(2 * 16 * 16, 0.01, np.float32), deterministic=True)
    assert action.shape == (n_actions(16),) and np.all(np.abs(action) <= 1)


def test_balance_shares_equal_a_cell_by_cell_count_of_the_rows_above_and_below():
    """`balance`'s inputs against the plain definition, cell by cell: the defenders' share in
    the rows above the cell's and below it, and the intruders' share of the intruder mass left
    on the map there; the same on every cell of a row; 0 where nothing is left."""
    from farm.alloc.networks.cell_policy import balance_shares

    rng = np.random.default_rng(5)
    n, B = 7, 3
    densities = rng.dirichlet(np.ones(n * n), size=(B, 2)).reshape(B, 2, n, n)
    densities[:, 1] *= np.array([1.0, 0.3, 0.0])[:, None, None]  # intruders partly eliminated, then all
    densities[0, :, 2, :] = 0.0  # an empty row
    got = balance_shares(torch.as_tensor(densities, dtype=torch.float32)).numpy()
    assert got.shape == (B, 4, n, n)
    for b in range(B):
        left = densities[b, 1].sum()
        for r in range(n):
            for c in range(n):
                want = [densities[b, 0, :r].sum(), densities[b, 0, r + 1:].sum(),
                        densities[b, 1, :r].sum() / left if left > 0 else 0.0,
                        densities[b, 1, r + 1:].sum() / left if left > 0 else 0.0]
                np.testing.assert_allclose(got[b, :, r, c], want, atol=1e-6)


def test_a_balance_policy_keeps_its_option_and_weights_on_another_map():
    """resized() keeps `balance` (its first layer reads 4 more channels) and the weights, and
    the policy acts on the other map."""
    import gymnasium as gym

    from farm.alloc.networks.cell_policy import CellPolicy, resized

    policy = CellPolicy(gym.spaces.Box(0.0, 1.0, (2 * 4 * 4,), np.float32),
                        gym.spaces.Box(-1.0, 1.0, (n_actions(4),), np.float32), lambda _: 1e-3, channels=8, layers=2,
                        teams=(10, 5), lateral=True, balance=True)
    other = resized(policy, SCENARIOS["theatre_16x16"].config())
    assert other.balance and other.lateral and other.grid == 16
    mine = {k: v for k, v in policy.state_dict().items() if k != "log_std"}
    assert all(torch.equal(other.state_dict()[k], v) for k, v in mine.items())
    action, _ = other.predict(np.full(2 * 16 * 16, 0.01, np.float32), deterministic=True)
    assert action.shape == (n_actions(16),) and np.all(np.abs(action) <= 1)
