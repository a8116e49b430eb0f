"""Engagement model v2 (docs/model.md section 5): defaults, the window tied to the step,
elimination from the captured fraction only, v1 still reachable, behaviour measures."""

import numpy as np
import pytest
from pydantic import ValidationError

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.alloc.allocators.baselines import StayAtBase
from farm.alloc.evaluation.rollout import run_episode, step_means
from farm.service import CaptureTimeClient
from workers import Case, InitialLaw

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=8)


def test_v2_is_the_default_and_couples_the_layers():
    c = AllocConfig()
    assert c.engagement == "v2"
    assert (c.pursuer_policy, c.evader_policy, c.exit_point) == ("pure_pursuit", "target", (0.0, 5.0))
    assert c.step_seconds == 10.0 and c.tau == 10.0 and c.t_max == 10.0 and c.capture_time_norm == 10.0
    game = c.game_settings().game
    assert (game.pursuer_policy, game.evader_policy, game.exit_point, game.target) == \
        ("pure_pursuit", "target", (0.0, 5.0), (0.0, 5.0))
    assert (game.tau, game.t_max, game.law) == (10.0, 10.0, InitialLaw())


def test_tau_follows_from_the_step():
    assert AllocConfig(step_seconds=6.0).window_defaults() == \
        {"step_seconds": 6.0, "tau": 6.0, "t_max": 6.0, "capture_time_norm": 6.0}
    slow = AllocConfig(evader_speed=0.5)  # crossing a 10 m cell takes 20 s
    assert (slow.step_seconds, slow.tau, slow.t_max) == (20.0, 20.0, 20.0)
    assert slow.game_settings().game.evader_speed == 0.5
    assert AllocConfig(t_max=15.0).t_max == 15.0  # longer games are allowed, only the window counts


@pytest.mark.parametrize("bad,message", [
    (dict(tau=5.0), "tau: under engagement v2 the window is the step"),
    (dict(step_seconds=8.0, tau=10.0), "tau: under engagement v2 the window is the step"),
    (dict(t_max=5.0), "t_max: the games (5 s) must last the window tau (10 s)"),
    (dict(engagement="v1", step_seconds=10.0), "step_seconds: only engagement v2"),
    (dict(engagement="v1", tau=5.0, t_max=4.0), "t_max: the games (4 s) must last the window tau (5 s)"),
])
def test_contradicting_overrides_are_one_clear_error(bad, message):
    with pytest.raises(ValidationError) as err:
        AllocConfig(**bad)
    assert message in str(err.value)


def test_v1_is_reachable_and_plays_the_earlier_games():
    c = AllocConfig(engagement="v1")
    assert (c.pursuer_policy, c.evader_policy, c.exit_point, c.step_seconds) == ("area_min", "centroid", None, None)
    assert (c.tau, c.t_max, c.capture_time_norm) == (5.0, 10.0, 10.0)
    game = c.game_settings().game
    # The same case as before engagement v2 existed (only the engine version moved).
    before = Case(1, 1, pursuer_policy="area_min", evader_policy="centroid", tau=5.0, t_max=10.0)
    assert game == before
    v2 = AllocConfig().game_settings()
    assert v2.key(3, 2).digest() != c.game_settings().key(3, 2).digest()


def engineered_step(env):
    """Defenders: 8 in the centre (cell 4), 2 at the base (cell 3); intruders 0.6 in cell 5
    move into the centre (3 intruders), 0.4 in cell 2 move to cell 1 (no defenders)."""
    env.reset(seed=0)
    env.D, env.I = np.zeros(9), np.zeros(9)
    env.D[4], env.D[3] = 0.8, 0.2
    env.I[5], env.I[2] = 0.6, 0.4
    stay = np.where(env.src == env.dst, 1.0, -1.0)
    D_next = np.bincount(env.dst, weights=env.move_probabilities(stay) * env.D[env.src], minlength=9)
    _, reward, _, _, info = env.step(stay)
    return D_next, reward, info


def test_elimination_is_the_captured_within_window_fraction_and_escapes_are_not(store):
    env = SwarmAllocationEnv(AllocConfig(**SMALL, c_capture=1.5), store=store)
    D_next, reward, info = engineered_step(env)
    n_p = int(np.rint(D_next[4] * 10))
    assert n_p == 8 and info["engaged_cells"] == 1
    v = CaptureTimeClient(env.config.game_settings(), local_store=store).get(n_p, 3)
    captured, escaped = v.frac_captured_tau, v.frac_escaped_tau
    assert 0 < captured < 1 and escaped > 0 and captured + escaped <= 1 + 1e-12  # the rest escape or still run
    assert env.I[4] == pytest.approx(0.6 * (1 - captured), abs=1e-12)
    assert info["eliminated_step"] == pytest.approx(0.6 * captured, abs=1e-12)  # the escaped are not eliminated
    # the expected capture score: captures that do not happen within the window earn nothing
    assert 0 < v.capture_score_tau <= captured
    assert reward == pytest.approx(-(env.I.sum()) + 1.5 * 0.6 * v.capture_score_tau, abs=1e-12)
    assert info["coverage"] == pytest.approx(0.6 / 1.0) and info["defenders_per_engaged"] == 8


def test_behaviour_measures_on_a_known_episode(store):
    """Stay at base: step 1 the intruders reach the middle column (no defenders), step 2 the
    left column, where the base cell (row 1) holds all 10 defenders, step 3 they breach."""
    env = SwarmAllocationEnv(AllocConfig(**SMALL), store=store)
    policy = StayAtBase(3)
    env.reset(seed=4)
    start = env.I.reshape(3, 3)[:, 2].copy()  # the right column's masses, rows 0..2
    episode = run_episode(env, policy, seed=4)
    summary, per_step = episode.summary, episode.steps
    assert summary["length"] == 3
    assert per_step[0].tolist()[:2] == [0.0, 0.0] and np.isnan(per_step[0][2])
    assert per_step[1][0] == pytest.approx(start[1] / start.sum()) and per_step[1][1:].tolist() == [1, 10]
    assert per_step[2].tolist()[:2] == [0.0, 0.0]
    assert summary["coverage"] == pytest.approx(start[1] / start.sum() / 3)
    assert summary["engaged"] == pytest.approx(1 / 3) and summary["defenders_per_engaged"] == 10
    assert summary["breached"] + summary["eliminated"] == pytest.approx(1.0)
    means = step_means([per_step, per_step[:2]])
    assert means.shape == (3, 3) and means[1, 2] == 10 and means[2, 0] == 0.0


def test_service_keys_are_those_of_version_0_1_and_old_run_configs_load():
    """The one-game-model rewrite (0.2) kept every service key: stores filled before it are
    read, not recomputed (digests computed with the 0.1 code). A run folder's config.yaml of
    0.1 spelled the intruders' speed `intruder_speed` and the law as a string; both load."""
    assert AllocConfig().game_settings().key(3, 2).digest() == \
        "ab4b3e760670ab5b272f9d81a3182cd616a606c737f40d020bf2b4bf0bbe2a8b"
    assert AllocConfig(engagement="v1").game_settings().key(3, 2).digest() == \
        "33dd228300ead1832ceb5875f2fbcf6dc8b89b0005ff174f20eb10533e55472f"
    new = AllocConfig(evader_speed=0.5, law={"kind": "uniform"})
    assert new.game_settings().key(3, 2).digest() == \
        "4afe351b211022ecfd2d2f88599fd5174192e5eae3d0ad9cb559d350db603153"
    assert AllocConfig(intruder_speed=0.5, law="uniform") == new


def test_game_settings_come_from_case():
    """Every workers.Case setting but the team sizes is an AllocConfig field, none other is
    declared twice, and Case's checks apply."""
    from farm.core.config import SETTING_FIELDS

    assert set(SETTING_FIELDS) <= set(AllocConfig.model_fields)
    assert AllocConfig(capture_radius=0.5).game_settings().game.capture_radius == 0.5
    assert AllocConfig().game_settings().game.capture_radius == Case(1, 1).capture_radius
    with pytest.raises(ValidationError, match="capture_radius: must be positive and finite"):
        AllocConfig(capture_radius=-1.0)
    with pytest.raises(ValidationError, match="n_pursuers"):
        AllocConfig(n_pursuers=3)
