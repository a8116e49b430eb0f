"""The capture score as an expectation over all of a cell's games (docs/model.md section 5).

A game in which nobody is caught within tau scores 0; a cell scores its intruder mass
times the mean over all its games of each game's mean of max(0, 1 - t/tau) per intruder.
"""

import math

import numpy as np
import pandas as pd
import pytest

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.alloc.game.model import EngagementModel
from farm.service import CaptureTimeClient
from farm.service.lookup import Lookup
from farm.service.store import StatsStore
from workers import CaptureStats, game_statistics, run_games

TAU = 10.0


def halves(n_e: int, games: int = 4) -> np.ndarray:
    """Capture times (games, n_e): half of each game's intruders caught at tau/2, the rest never."""
    t = np.full((games, n_e), np.nan)
    t[:, : n_e // 2] = TAU / 2
    return t


def test_half_caught_at_half_tau_scores_a_quarter():
    stats = CaptureStats.from_games(game_statistics(halves(4), TAU))
    assert stats.capture_score_tau == pytest.approx(0.25)
    assert stats.frac_captured_tau == pytest.approx(0.5)
    # the earlier, conditional rule pays 1 - (tau/2)/tau = 0.5 for the same games
    assert 1 - stats.mean_capture.mean / TAU == pytest.approx(0.5)


def test_games_that_catch_nobody_score_zero_and_count():
    """Half the games catch everybody at t = 0, half catch nobody: the mean over all games is 0.5."""
    t = np.vstack([np.zeros((3, 2)), np.full((3, 2), np.nan)])
    per = game_statistics(t, TAU)
    assert list(per["capture_score_tau"]) == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    assert CaptureStats.from_games(per).capture_score_tau == pytest.approx(0.5)


def test_captures_after_tau_score_zero():
    t = np.array([[TAU + 1.0, TAU], [TAU * 0.9, np.nan]])
    per = game_statistics(t, TAU)
    np.testing.assert_allclose(per["capture_score_tau"], [0.0, 0.05])


def test_score_matches_a_slow_computation(rng):
    """Against an obvious loop over games and intruders."""
    t = rng.uniform(0, 2 * TAU, size=(50, 5))
    t[rng.random(t.shape) < 0.3] = np.nan
    slow = np.mean([np.mean([max(0.0, 1 - x / TAU) if (not math.isnan(x) and x <= TAU) else 0.0 for x in game])
                    for game in t])
    assert CaptureStats.from_games(game_statistics(t, TAU)).capture_score_tau == pytest.approx(slow, abs=1e-12)


class FixedGames(Lookup):
    """A lookup without a store whose every case's games are the given capture times."""

    repeatable = True

    def __init__(self, capture_times):
        def compute(keys):
            for k, key in enumerate(keys):
                yield k, CaptureStats.from_games(game_statistics(capture_times(key.case.n_evaders), key.case.tau))
        super().__init__(None, compute)


def fixed_client(settings, capture_times):
    """A client whose games of n_e intruders are capture_times(n_e): (games, n_e) float64."""
    return CaptureTimeClient(settings, backend=FixedGames(capture_times))


@pytest.mark.parametrize("rule, per_mass", [("expected", 0.25), ("conditional", 0.5)])
def test_env_pays_the_rule(rule, per_mass):
    """An engaged cell of mass 0.4 whose games catch half its intruders at tau/2: the env's capture
    score is 0.4 * 0.25 under the expected rule (0.4 * 0.5 under the earlier one)."""
    cfg = AllocConfig(grid_size=3, n_defenders=10, n_intruders=10, c_distribution=0.0, c_capture=1.0,
                      breach_penalty=0.0, capture_score=rule)
    env = SwarmAllocationEnv(cfg, client=fixed_client(cfg.game_settings(), halves))
    env.reset(seed=0)
    env.D = np.zeros(9)
    env.D[4] = 1.0
    env.I = np.zeros(9)
    env.I[5] = 0.4  # advances into the centre, where all the defenders stay
    stay = np.where(env.src == env.dst, 1.0, -1.0)
    _, reward, _, _, info = env.step(stay)
    assert info["engaged_cells"] == 1
    assert reward == pytest.approx(0.4 * per_mass)
    assert info["eliminated_step"] == pytest.approx(0.4 * 0.5)


def test_v1_keeps_the_conditional_rule_and_v2_refuses_another_norm():
    assert AllocConfig().capture_score == "expected"
    assert AllocConfig(engagement="v1").capture_score == "conditional"
    with pytest.raises(ValueError, match="capture_time_norm: the expected capture score is normalised by"):
        AllocConfig(capture_time_norm=8.0)
    assert AllocConfig(capture_time_norm=8.0, capture_score="conditional").capture_time_norm == 8.0


def test_model_rates_use_the_client(tmp_path):
    """The planners' model answers what the env pays: the service's capture_score_tau per unit of mass."""
    cfg = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5, games=3)
    client = CaptureTimeClient(cfg.game_settings(), local_store=tmp_path / "s.sqlite")
    removed, score, estimates = EngagementModel(cfg, client).rates(np.array([3, 1]), np.array([1, 2]))
    values = client.get_many([(3, 1), (1, 2)])
    np.testing.assert_array_equal(removed, [v.frac_captured_tau for v in values])
    np.testing.assert_array_equal(score, [v.capture_score_tau for v in values])
    assert estimates == 0
    client.close()


def test_rows_written_without_the_score_are_recomputed_never_misread(tmp_path):
    """A store row of 0.3's layout (no capture_score_tau) is left out and its key recomputed."""
    cfg = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5, games=3)
    path = tmp_path / "old.sqlite"
    settings = cfg.game_settings()
    key = settings.key(2, 1)
    client = CaptureTimeClient(settings, local_store=path)
    fresh = client.get(2, 1)
    client.close()
    store = StatsStore(path)
    old = fresh.flat()
    del old["capture_score_tau_mean"]
    real = fresh.capture_score_tau
    store.put(key, CaptureStats.from_flat({**old, "capture_score_tau_mean": -1.0}))  # a row to overwrite
    import json

    from farm.service.store import _checksum_v2
    row = store.db.execute("SELECT key, settings, n_pursuers, n_evaders, key_json FROM stats").fetchone()
    value_json = json.dumps(old, sort_keys=True)
    store.db.execute("UPDATE stats SET value_json = ?, checksum = ?", (value_json, _checksum_v2(*row, value_json)))
    assert store.get(key) is None and store.older_rows == {key.digest()}
    store.close()
    client = CaptureTimeClient(settings, local_store=path)
    again = client.get(2, 1)
    assert again.capture_score_tau == pytest.approx(real)
    assert client.stats()["computations"] == {key.digest(): 1}
    client.close()
    assert StatsStore(path).get(key).capture_score_tau == pytest.approx(real)


def test_score_of_real_games_from_their_times():
    """The service's statistic equals the definition applied to the engine's raw capture times."""
    cfg = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5)
    case = cfg.game_settings().key(3, 2).case
    res = run_games(case, 0, 0, 16)
    ct = res.capture_times
    by_hand = np.mean(np.where(np.isfinite(ct) & (ct <= case.tau + 1e-9), np.maximum(0, 1 - ct / case.tau), 0.0))
    per = game_statistics(ct, case.tau)
    assert CaptureStats.from_games(pd.DataFrame(per)).capture_score_tau == pytest.approx(by_hand)
