"""Escapes (docs/model.md section 1, "Escape") and team speeds in the batched engine,
against analytic values and the slow reference (tests/shapely_reference.py).

GameResults fields used here (B games, n_e evaders):
  capture_times (B, n_e) float64, NaN = not captured;  capture_step (B, n_e) int64, -1
  escape_times  (B, n_e) float64, NaN = not escaped;   escape_step  (B, n_e) int64, -1
  steps (B,) int64; with record=True pursuer_paths (T+1, B, n_p, 2) and
  evader_paths (T+1, B, n_e, 2) float64; alive_at(frame) (B, n_e) bool.
"""

import math

import numpy as np
import pytest
from shapely_reference import reference_game

from workers import InputError, simulate_games

DT, RC = 0.01, 0.25
EXIT = (0.0, 5.0)


def _first_step_below(d0, per_step, rc=RC):
    """First k >= 1 with d0 - k * per_step < rc, and the distance to the nearest tie."""
    k = next(k for k in range(1, 10**7) if d0 - k * per_step < rc)
    margin = min(rc - (d0 - k * per_step), (d0 - (k - 1) * per_step) - rc)
    return k, margin


def _games(*rows):
    """(B, n, 2) float64 from B lists of n points."""
    return np.array(rows, dtype=np.float64)


def _dist(a, b):
    """Euclidean distance over the last axis (as the reference computes it)."""
    d = np.asarray(a) - np.asarray(b)
    return np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])


def _assert_results_equal(a, b):
    """Two GameResults with identical outcomes (NaNs equal)."""
    for name in ("capture_times", "escape_times"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    for name in ("capture_step", "escape_step", "steps"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


# --------------------------------------------------------------------------
# Analytic escapes
# --------------------------------------------------------------------------
@pytest.mark.parametrize(
    "evader_speed, starts",
    [
        (1.0, [(3.004, 5.0), (1.2345, 5.0), (7.0071, 5.0), (6.004, 8.0)]),
        (0.5, [(3.004, 5.0), (1.2345, 5.0)]),
    ],
)
def test_unguarded_evader_escapes_at_the_analytic_step(evader_speed, starts):
    """A `target` evader runs straight for the exit (its target) with the only
    pursuer far behind: it escapes at the first k+1 with
    d0 - (k+1) dt v_e < r_c, and the game ends there."""
    P = _games(*[[(9.9, 9.9)]] * len(starts))
    E = _games(*[[s] for s in starts])
    res = simulate_games(P, E, pursuer_policy="pure_pursuit", evader_policy="target", target=EXIT,
                         exit_point=EXIT, evader_speed=evader_speed)
    assert res.escape_times.dtype == np.float64 and res.escape_times.shape == (len(starts), 1)
    assert res.escape_step.dtype == np.int64 and res.escape_step.shape == (len(starts), 1)
    for b, start in enumerate(starts):
        k1, margin = _first_step_below(math.dist(start, EXIT), DT * evader_speed)
        assert margin > 1e-6
        assert res.escape_step[b, 0] == k1
        assert res.escape_times[b, 0] == k1 * DT
        assert np.isnan(res.capture_times[b, 0]) and res.capture_step[b, 0] == -1
        assert res.steps[b] == k1


def test_events_at_time_zero_capture_checked_first():
    """At t = 0: evader 0 is within r_c of the pursuer and of the exit (captured),
    evader 1 only of the exit (escaped), evader 2 of neither (still running at t_max)."""
    res = simulate_games(_games([(0.2, 5.1)]), _games([(0.1, 5.0), (0.0, 4.8), (6.0, 9.0)]),
                         pursuer_policy="pure_pursuit", evader_policy="target", exit_point=EXIT, t_max=0.5)
    np.testing.assert_array_equal(res.capture_step, [[0, -1, -1]])
    np.testing.assert_array_equal(res.escape_step, [[-1, 0, -1]])
    np.testing.assert_array_equal(res.capture_times, [[0.0, np.nan, np.nan]])
    np.testing.assert_array_equal(res.escape_times, [[np.nan, 0.0, np.nan]])
    assert res.steps[0] == 50
    np.testing.assert_array_equal(res.alive_at(0), [[False, False, True]])


def test_capture_wins_a_tie():
    """After step 0 the evader is 0.245 from the exit and ~0.2452 from the pursuer
    (neither below r_c before the move): game 0 captures it at step 1. Game 1,
    without the pursuer nearby, lets it escape at step 1."""
    P = _games([(0.255, 5.255)], [(9.0, 9.0)])
    E = _games([(0.255, 5.0)], [(0.255, 5.0)])
    res = simulate_games(P, E, pursuer_policy="pure_pursuit", evader_policy="target", exit_point=EXIT)
    np.testing.assert_array_equal(res.capture_step, [[1], [-1]])
    np.testing.assert_array_equal(res.escape_step, [[-1], [1]])
    np.testing.assert_array_equal(res.capture_times, [[0.01], [np.nan]])
    np.testing.assert_array_equal(res.escape_times, [[np.nan], [0.01]])
    np.testing.assert_array_equal(res.steps, [1, 1])


def test_escaped_evader_stops_and_is_no_longer_chased():
    """Evader 0 runs left along y = 5 for its target (0, 5) and passes the exit
    (2, 5): it escapes at step 16. Evader 1 is parked on the target. The pursuer
    (4, 8) chases evader 0 (the nearer) until the escape, then heads straight for
    evader 1 and catches it at the first step within r_c; the game ends there."""
    res = simulate_games(_games([(4.0, 8.0)]), _games([(2.4035, 5.0), (0.0, 5.0)]), pursuer_policy="pure_pursuit",
                         evader_policy="target", target=(0.0, 5.0), exit_point=(2.0, 5.0), record=True)
    k_esc, _ = _first_step_below(0.4035, DT)
    assert k_esc == 16
    assert res.escape_step[0].tolist() == [k_esc, -1]
    assert res.escape_times[0, 0] == k_esc * DT
    p, e = res.pursuer_paths[:, 0, 0], res.evader_paths[:, 0]
    # after the escape, the pursuer goes straight for the parked evader 1
    k_cap, margin = _first_step_below(float(_dist(p[k_esc], e[0, 1])), DT)
    assert margin > 1e-6
    assert res.capture_step[0].tolist() == [-1, k_esc + k_cap]
    assert res.capture_times[0, 1] == pytest.approx((k_esc + k_cap) * DT, abs=1e-12)
    assert np.isnan(res.capture_times[0, 0]) and np.isnan(res.escape_times[0, 1])
    assert res.steps[0] == k_esc + k_cap
    assert len(res.pursuer_paths) == res.steps[0] + 1
    # the escaped evader does not move after its escape
    np.testing.assert_array_equal(e[k_esc:, 0], np.broadcast_to(e[k_esc, 0], e[k_esc:, 0].shape))
    # unit-speed pursuit of evader 0 before the escape, of evader 1 after it
    for f in range(res.steps[0]):
        goal = e[f, 0] if f < k_esc else e[f, 1]
        heading = (goal - p[f]) / _dist(goal, p[f])
        np.testing.assert_allclose(p[f + 1] - p[f], DT * heading, atol=1e-12)
    np.testing.assert_array_equal(res.alive_at(k_esc - 1), [[True, True]])
    np.testing.assert_array_equal(res.alive_at(k_esc), [[False, True]])
    np.testing.assert_array_equal(res.alive_at(res.steps[0]), [[False, False]])
    # the slow reference agrees
    ref_c, ref_e = reference_game([(4.0, 8.0)], [(2.4035, 5.0), (0.0, 5.0)], pursuer_policy="pure_pursuit",
                                  evader_policy="target", exit_point=(2.0, 5.0), return_escapes=True)
    np.testing.assert_array_equal(res.capture_times[0], ref_c)
    np.testing.assert_array_equal(res.escape_times[0], ref_e)


# --------------------------------------------------------------------------
# Invariants of random games
# --------------------------------------------------------------------------
@pytest.mark.parametrize("pp, ep", [("pure_pursuit", "target"), ("area_min", "target"), ("area_min", "centroid")])
def test_escapes_and_captures_never_overlap(pp, ep, rng):
    """Random games with the exit at (0, 5): no evader both captured and escaped;
    each event happens at the first frame where its condition holds (capture
    first); the game runs until every evader is out, or to t_max."""
    B, n_p, n_e, t_max = 6, 3, 4, 10.0
    P = np.stack([rng.uniform(3, 5, (B, n_p)), rng.uniform(0, 10, (B, n_p))], -1)
    E = rng.uniform(0, 10, (B, n_e, 2))
    res = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep, exit_point=EXIT, t_max=t_max, record=True)
    cap, esc = res.capture_step, res.escape_step
    assert not np.any(np.isfinite(res.capture_times) & np.isfinite(res.escape_times))
    assert not np.any((cap >= 0) & (esc >= 0))
    np.testing.assert_array_equal(np.isnan(res.capture_times), cap < 0)
    np.testing.assert_array_equal(np.isnan(res.escape_times), esc < 0)
    np.testing.assert_array_equal(res.capture_times[cap >= 0], cap[cap >= 0] * DT)
    np.testing.assert_array_equal(res.escape_times[esc >= 0], esc[esc >= 0] * DT)
    n_steps = round(t_max / DT)
    for b in range(B):
        ev = np.maximum(cap[b], esc[b])
        assert res.steps[b] == (ev.max() if np.all(ev >= 0) else n_steps)
        for i in range(n_e):
            s = ev[i]
            if s < 0:
                continue
            near_p = _dist(res.evader_paths[s, b, i], res.pursuer_paths[s, b]).min() < RC
            near_x = _dist(res.evader_paths[s, b, i], EXIT) < RC
            if cap[b, i] >= 0:
                assert near_p
            else:
                assert near_x and not near_p
            if s > 0:  # not out one frame earlier
                assert _dist(res.evader_paths[s - 1, b, i], res.pursuer_paths[s - 1, b]).min() >= RC
                assert _dist(res.evader_paths[s - 1, b, i], EXIT) >= RC
            # out of the game: frozen from then on, and alive_at says so
            frozen = res.evader_paths[s:, b, i]
            np.testing.assert_array_equal(frozen, np.broadcast_to(frozen[0], frozen.shape))
            assert not res.alive_at(s)[b, i]
            if s > 0:
                assert res.alive_at(s - 1)[b, i]
    if ep == "target":  # evaders heading for the exit: both outcomes occur
        assert (cap >= 0).any() and (esc >= 0).any()


# --------------------------------------------------------------------------
# Against the reference
# --------------------------------------------------------------------------
def test_no_exit_is_unchanged_and_matches_reference_on_paper_cases(rng):
    """exit_point=None is the paper's game: identical to omitting the argument,
    no escapes, and bit-identical to the reference on the Table 1 cases."""
    B = 3
    for n_p in (1, 3, 5):
        P = np.stack([rng.uniform(3, 5, (B, n_p)), rng.uniform(0, 10, (B, n_p))], -1)
        E = np.stack([rng.uniform(7, 9, (B, 1)), rng.uniform(0, 10, (B, 1))], -1)
        kw = dict(pursuer_policy="pure_pursuit", evader_policy="target")
        plain = simulate_games(P, E, **kw)
        none = simulate_games(P, E, exit_point=None, pursuer_speed=1.0, evader_speed=1.0, **kw)
        _assert_results_equal(plain, none)
        assert np.isnan(none.escape_times).all() and (none.escape_step == -1).all()
        ref = np.array([reference_game(P[b], E[b], **kw) for b in range(B)])
        assert np.array_equal(none.capture_times, ref, equal_nan=True)


def _compare_with_reference(P, E, pp, ep, t_max, **kw):
    """(entries equal, entries compared) over capture and escape times of B games;
    asserts equal NaN patterns and no time differing by more than 0.25 s."""
    res = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep, t_max=t_max, **kw)
    refs = [reference_game(P[b], E[b], pursuer_policy=pp, evader_policy=ep, t_max=t_max, return_escapes=True, **kw)
            for b in range(len(P))]
    exact = total = 0
    for ours, ref in [(res.capture_times, np.array([r[0] for r in refs])),
                      (res.escape_times, np.array([r[1] for r in refs]))]:
        assert np.array_equal(np.isnan(ours), np.isnan(ref))
        both = ~np.isnan(ours)
        assert np.all(np.abs(ours[both] - ref[both]) <= 0.25)
        exact += int(np.sum(ours[both] == ref[both]) + np.sum(~both))
        total += ours.size
    return exact, total


@pytest.mark.parametrize("pp, ep", [("pure_pursuit", "target"), ("area_min", "target"),
                                    pytest.param("area_min", "centroid", marks=pytest.mark.slow)])
def test_escape_times_match_reference(pp, ep, rng):
    """Whole games with the exit at (0, 5): same outcomes as the reference, times
    identical except where round-off is amplified into a few steps' difference."""
    exact = total = 0
    for n_p, n_e in [(1, 1), (3, 1), (2, 3)]:
        P, E = rng.random((2, n_p, 2)) * 10, rng.random((2, n_e, 2)) * 10
        x, n = _compare_with_reference(P, E, pp, ep, 10.0, exit_point=EXIT)
        exact, total = exact + x, total + n
    assert exact / total >= 0.8


# --------------------------------------------------------------------------
# Team speeds
# --------------------------------------------------------------------------
def test_double_pursuer_speed_against_stationary_evader():
    """An evader parked on its target (0, 5) is caught at the first k with
    d - k dt v_p < r_c, v_p = 2."""
    ds = [1.003, 2.347, 5.005]
    res = simulate_games(_games(*[[(d, 5.0)] for d in ds]), _games(*[[(0.0, 5.0)]] * len(ds)),
                         pursuer_policy="pure_pursuit", evader_policy="target", pursuer_speed=2.0)
    for b, d in enumerate(ds):
        k1, margin = _first_step_below(d, 2.0 * DT)
        assert margin > 1e-6
        assert res.capture_step[b, 0] == k1
        assert res.capture_times[b, 0] == k1 * DT
        assert res.steps[b] == k1


@pytest.mark.parametrize(
    "pp, ep, kw",
    [
        ("pure_pursuit", "target", dict(pursuer_speed=2.0)),
        ("area_min", "centroid", dict(pursuer_speed=2.0)),
        ("pure_pursuit", "target", dict(pursuer_speed=0.8, evader_speed=1.5, exit_point=EXIT)),
    ],
)
def test_team_speeds_match_reference(pp, ep, kw, rng):
    exact = total = 0
    for n_p, n_e in [(1, 1), (2, 3)]:
        P, E = rng.random((2, n_p, 2)) * 10, rng.random((2, n_e, 2)) * 10
        x, n = _compare_with_reference(P, E, pp, ep, 10.0, **kw)
        exact, total = exact + x, total + n
    assert exact / total >= 0.8


# --------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, value",
    [
        ("exit_point", (np.nan, 5.0)),
        ("exit_point", (0.0, np.inf)),
        ("exit_point", (1.0, 2.0, 3.0)),
        ("exit_point", [[0.0, 5.0]]),
        ("exit_point", "exit"),
        ("pursuer_speed", 0.0),
        ("pursuer_speed", -1.0),
        ("pursuer_speed", np.nan),
        ("pursuer_speed", np.inf),
        ("evader_speed", 0.0),
        ("evader_speed", -1.0),
        ("evader_speed", np.nan),
        ("evader_speed", np.inf),
    ],
)
def test_bad_exit_point_and_speeds_raise_input_error(name, value):
    with pytest.raises(InputError) as info:
        simulate_games(_games([(1.0, 1.0)]), _games([(9.0, 9.0)]), t_max=0.1, **{name: value})
    message = str(info.value)
    assert message.startswith(f"{name}: ")
    assert "\n" not in message
