"""Sanity checks of the slow reference implementation (tests/shapely_reference.py)."""

import math

import numpy as np
import pytest
import shapely
from shapely_reference import reference_cells, reference_game, reference_velocities

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
HEXAGON = np.array(
    [[5.0 + 5.0 * math.cos(a), 5.0 + 5.0 * math.sin(a)] for a in np.arange(6) * math.pi / 3]
)
TRIANGLE = np.array([[0.0, 0.0], [10.0, 0.0], [3.0, 8.0]])


def _random_points_in(arena, n, rng):
    poly = shapely.Polygon(arena)
    xmin, ymin, xmax, ymax = poly.bounds
    pts = []
    while len(pts) < n:
        p = rng.uniform([xmin, ymin], [xmax, ymax])
        if poly.contains(shapely.Point(p)):
            pts.append(p)
    return np.array(pts)


def _halfplane_cell(points, i, arena):
    """Independent brute-force cell: the arena clipped by every bisector half-plane."""
    cell = shapely.Polygon(arena)
    big = 1e3
    for j, q in enumerate(points):
        if j == i:
            continue
        p = points[i]
        n = (q - p) / np.linalg.norm(q - p)
        m = (p + q) / 2
        t = np.array([-n[1], n[0]])
        half = shapely.Polygon([m + big * t, m + big * t - big * n, m - big * t - big * n, m - big * t])
        cell = cell.intersection(half)
    return cell


def _check_partition(points, arena):
    cells = reference_cells(points, arena)
    arena_area = shapely.Polygon(arena).area
    assert len(cells) == len(points)
    assert sum(c["area"] for c in cells) == pytest.approx(arena_area, abs=1e-9)
    for i, c in enumerate(cells):
        assert c["polygon"].contains(shapely.Point(c["centroid"]))
        assert c["area"] == pytest.approx(c["polygon"].area)
        assert c["polygon"].contains(shapely.Point(points[i])) or c["polygon"].touches(
            shapely.Point(points[i])
        )
        brute = _halfplane_cell(points, i, arena)
        assert c["polygon"].symmetric_difference(brute).area < 1e-9
        for j, (length, mid) in c["edges"].items():
            assert length > 1e-9
            # symmetric, and the midpoint is equidistant from both agents
            assert cells[j]["edges"][i][0] == pytest.approx(length)
            assert np.linalg.norm(mid - points[i]) == pytest.approx(np.linalg.norm(mid - points[j]))
            shared = c["polygon"].intersection(cells[j]["polygon"])
            assert shared.length == pytest.approx(length, abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cells_partition_square(seed):
    rng = np.random.default_rng(seed)
    _check_partition(rng.uniform(0, 10, size=(12, 2)), SQUARE)


@pytest.mark.parametrize("arena", [TRIANGLE, HEXAGON], ids=["triangle", "hexagon"])
def test_cells_partition_other_convex_arenas(arena):
    rng = np.random.default_rng(7)
    _check_partition(_random_points_in(arena, 10, rng), arena)


def test_cells_points_on_boundary_and_corners():
    pts = np.array([[0.0, 0.0], [10.0, 3.0], [5.0, 10.0], [0.0, 7.0], [4.0, 4.0]])
    _check_partition(pts, SQUARE)


def test_two_agents_cells():
    cells = reference_cells(np.array([[2.0, 5.0], [8.0, 5.0]]))
    for i, j in [(0, 1), (1, 0)]:
        assert cells[i]["area"] == pytest.approx(50.0, abs=1e-9)
        assert list(cells[i]["edges"]) == [j]
        length, mid = cells[i]["edges"][j]
        assert length == pytest.approx(10.0, abs=1e-9)
        np.testing.assert_allclose(mid, [5.0, 5.0], atol=1e-9)
    np.testing.assert_allclose(cells[0]["centroid"], [2.5, 5.0], atol=1e-9)
    np.testing.assert_allclose(cells[1]["centroid"], [7.5, 5.0], atol=1e-9)


def test_coincident_agents_share_a_cell():
    pts = np.array([[2.0, 5.0], [8.0, 5.0], [2.0, 5.0]])
    cells = reference_cells(pts)
    assert cells[2]["area"] == pytest.approx(50.0)
    assert list(cells[2]["edges"]) == [1]
    assert list(cells[1]["edges"]) == [0]


def test_two_agents_velocities():
    P, E = np.array([[2.0, 5.0]]), np.array([[8.0, 5.0]])
    for ep in ["centroid", "constant_area", "area_max"]:
        u_p, u_e = reference_velocities(
            P, E, np.array([True]), pursuer_policy="area_min", evader_policy=ep
        )
        np.testing.assert_allclose(u_p, [[1.0, 0.0]], atol=1e-12)
        np.testing.assert_allclose(u_e, [[-1.0, 0.0]], atol=1e-12)
    # dead evaders do not move; pursuers without live evaders stay put
    u_p, u_e = reference_velocities(
        P, E, np.array([False]), pursuer_policy="area_min", evader_policy="centroid"
    )
    assert not u_p.any() and not u_e.any()


def test_area_min_far_pursuer_uses_pure_pursuit():
    # pursuer 1 is hidden behind pursuer 0, so it is no neighbour of the evader
    P = np.array([[5.0, 5.0], [1.0, 5.0]])
    E = np.array([[9.0, 5.0]])
    u_p, _ = reference_velocities(P, E, [True], pursuer_policy="area_min", evader_policy="centroid")
    np.testing.assert_allclose(u_p, [[1.0, 0.0], [1.0, 0.0]], atol=1e-12)


@pytest.mark.parametrize("d", [3.004, 1.2345, 0.2537])
def test_pure_pursuit_on_parked_evader(d):
    dt, rc = 0.01, 0.25
    target = (5.0, 5.0)
    times = reference_game(
        [[5.0 + d, 5.0]],
        [target],
        pursuer_policy="pure_pursuit",
        evader_policy="target",
        capture_radius=rc,
        dt=dt,
        t_max=60.0,
        target=target,
    )
    k = 0
    while not d - (k + 1) * dt < rc:
        k += 1
    assert times[0] == (k + 1) * dt


def test_capture_at_time_zero_and_never():
    times = reference_game(
        [[5.0, 5.0]],
        [[5.1, 5.0], [9.0, 9.0]],
        pursuer_policy="pure_pursuit",
        evader_policy="target",
        target=(9.0, 9.0),
        t_max=1.0,
    )
    assert times[0] == 0.0
    assert math.isnan(times[1])  # 5.6 away, the pursuer covers 1.0 in t_max


def test_target_evader_lands_on_target():
    times = reference_game(
        [[0.5, 0.5]],
        [[5.0, 5.0]],
        pursuer_policy="pure_pursuit",
        evader_policy="target",
        target=(5.0, 5.003),
        t_max=0.05,
        capture_radius=0.0,
    )
    assert math.isnan(times[0])
    _, u_e = reference_velocities(
        [[0.5, 0.5]], [[5.0, 5.0]], [True], pursuer_policy="pure_pursuit",
        evader_policy="target", target=(5.0, 5.003),
    )
    np.testing.assert_allclose(u_e, [[0.0, 0.3]], atol=1e-9)


def test_projection_keeps_agents_in_arena():
    # The evader runs for a target outside the arena and must stop on the wall
    # x = 0 (it moves as fast as the pursuer, so it would never be caught in
    # the open before reaching its target at t = 3.5).
    dt, rc, x0 = 0.01, 0.25, 5.004
    times = reference_game(
        [[x0, 5.0]],
        [[0.5, 5.0]],
        pursuer_policy="pure_pursuit",
        evader_policy="target",
        target=(-3.0, 5.0),
        capture_radius=rc,
        dt=dt,
        t_max=6.0,
    )
    k = 0
    while not x0 - (k + 1) * dt < rc:
        k += 1
    assert times[0] == pytest.approx((k + 1) * dt, abs=1e-12)


def test_voronoi_game_captures_as_the_compiled_engine_does():
    """A 2 v 2 area_min / centroid game: both evaders caught, at the compiled engine's steps
    (two implementations that share no code)."""
    from workers import simulate_games

    pursuers, evaders = [[1.0, 1.0], [9.0, 1.0]], [[5.0, 8.0], [2.0, 6.0]]
    times = reference_game(pursuers, evaders, pursuer_policy="area_min", evader_policy="centroid", t_max=30.0)
    engine = simulate_games(np.array([pursuers]), np.array([evaders]), pursuer_policy="area_min",
                            evader_policy="centroid", t_max=30.0)
    np.testing.assert_allclose(times, engine.capture_times[0], atol=1e-9)
    np.testing.assert_allclose(times, [15.73, 9.82], atol=1e-9)


def test_nearly_coincident_agents_do_not_crash():
    pts = np.array([[2.0, 5.0], [8.0, 5.0], [2.0 + 2e-12, 5.0], [2.0, 5.0 + 1e-13]])
    cells = reference_cells(pts)
    assert len(cells) == 4
    assert all(c["area"] > 0 for c in cells)
    times = reference_game(
        [[2.0, 2.0], [2.0, 2.0]],
        [[8.0, 8.0], [8.0, 8.0 + 1e-13]],
        pursuer_policy="area_min",
        evader_policy="area_max",
        t_max=2.0,
    )
    assert times.shape == (2,)


# --------------------------------------------------------------------------
# Escapes (exit_point) and team speeds (pursuer_speed, evader_speed)
# --------------------------------------------------------------------------
def _first_step_below(d0, per_step, rc=0.25):
    """First k >= 1 with d0 - k * per_step < rc, and how far that is from a tie."""
    k = next(k for k in range(1, 10**7) if d0 - k * per_step < rc)
    margin = min(rc - (d0 - k * per_step), (d0 - (k - 1) * per_step) - rc)
    return k, margin


@pytest.mark.parametrize(
    "start, evader_speed",
    [((3.004, 5.0), 1.0), ((1.2345, 5.0), 1.0), ((7.0071, 5.0), 1.0), ((3.004, 5.0), 0.5), ((1.2345, 5.0), 0.5)],
)
def test_evader_escapes_at_the_analytic_step(start, evader_speed):
    """A `target` evader runs straight at the unguarded exit (its target); the
    far pursuer never gets close, so it escapes at the first k+1 with
    |start - exit| - (k+1) dt v_e < r_c."""
    dt, rc, exit_point = 0.01, 0.25, (0.0, 5.0)
    d0 = math.dist(start, exit_point)
    k1, margin = _first_step_below(d0, dt * evader_speed, rc)
    assert margin > 1e-6
    captures, escapes = reference_game(
        [[9.9, 9.9]], [start], pursuer_policy="pure_pursuit", evader_policy="target",
        target=exit_point, exit_point=exit_point, evader_speed=evader_speed, return_escapes=True,
    )
    assert math.isnan(captures[0])
    assert escapes[0] == k1 * dt
    assert captures.dtype == escapes.dtype == np.float64 and escapes.shape == (1,)


def test_escape_defaults_unchanged():
    """Without exit_point / return_escapes: same (n_e,) array as before; an exit
    far out of reach changes nothing; escape times all NaN without an exit."""
    kw = dict(pursuer_policy="pure_pursuit", evader_policy="target", t_max=4.0)
    P, E = [[4.0, 3.0], [4.5, 8.0]], [[8.0, 6.0], [7.5, 1.0]]
    plain = reference_game(P, E, **kw)
    assert isinstance(plain, np.ndarray) and plain.shape == (2,) and plain.dtype == np.float64
    captures, escapes = reference_game(P, E, return_escapes=True, **kw)
    assert np.array_equal(plain, captures, equal_nan=True)
    assert np.isnan(escapes).all()
    far = reference_game(P, E, exit_point=(10.0, 10.0), **kw)
    assert np.array_equal(plain, far, equal_nan=True)
    explicit = reference_game(P, E, exit_point=None, pursuer_speed=1.0, evader_speed=1.0, **kw)
    assert np.array_equal(plain, explicit, equal_nan=True)


def test_events_at_time_zero_capture_first():
    """At t = 0: evader 0 is within r_c of the pursuer AND of the exit (captured),
    evader 1 only of the exit (escaped), evader 2 of neither."""
    captures, escapes = reference_game(
        [[0.2, 5.1]], [[0.1, 5.0], [0.0, 4.8], [6.0, 9.0]],
        pursuer_policy="pure_pursuit", evader_policy="target", exit_point=(0.0, 5.0),
        t_max=0.5, return_escapes=True,
    )
    assert captures[0] == 0.0 and math.isnan(escapes[0])
    assert escapes[1] == 0.0 and math.isnan(captures[1])
    assert math.isnan(captures[2]) and math.isnan(escapes[2])


def test_capture_wins_a_tie_at_a_step():
    """After step 0 the evader is 0.245 from the exit and ~0.2452 from the
    pursuer (both < r_c; neither before the move): it is captured, not escaped."""
    captures, escapes = reference_game(
        [[0.255, 5.255]], [[0.255, 5.0]], pursuer_policy="pure_pursuit", evader_policy="target",
        exit_point=(0.0, 5.0), return_escapes=True,
    )
    assert captures[0] == 0.01 and math.isnan(escapes[0])
    # the same game without the pursuer's help: escaped at that step
    captures, escapes = reference_game(
        [[9.0, 9.0]], [[0.255, 5.0]], pursuer_policy="pure_pursuit", evader_policy="target",
        exit_point=(0.0, 5.0), return_escapes=True,
    )
    assert escapes[0] == 0.01 and math.isnan(captures[0])


def test_escaped_evader_leaves_the_game():
    """Evader 0 runs left along y = 5 for its target (0, 5) and passes the exit
    (2, 5), escaping at step 16; evader 1 is parked on the target.  The pursuer
    (4.004, 5) chases evader 0 along the same line, then evader 1, so it moves
    left at unit speed throughout, runs over evader 0's escape position without
    capturing it, and catches evader 1 at the first k with 4.004 - k dt < r_c."""
    captures, escapes = reference_game(
        [[4.004, 5.0]], [[2.4035, 5.0], [0.0, 5.0]], pursuer_policy="pure_pursuit",
        evader_policy="target", target=(0.0, 5.0), exit_point=(2.0, 5.0), return_escapes=True,
    )
    k_escape, _ = _first_step_below(0.4035, 0.01)
    k_capture, _ = _first_step_below(4.004, 0.01)
    assert (k_escape, k_capture) == (16, 376)
    np.testing.assert_array_equal(escapes, [k_escape * 0.01, np.nan])
    np.testing.assert_array_equal(captures, [np.nan, k_capture * 0.01])


@pytest.mark.parametrize("d", [3.004, 1.2345, 5.005])
def test_double_pursuer_speed_halves_pure_pursuit_time(d):
    """A parked evader: caught at the first k+1 with d - (k+1) dt v_p < r_c; with
    v_p = 2 that is half the v_p = 1 time up to one step."""
    dt, rc, target = 0.01, 0.25, (5.0, 5.0)
    times = {}
    for v in (1.0, 2.0):
        k1, margin = _first_step_below(d, dt * v, rc)
        assert margin > 1e-6
        times[v] = reference_game(
            [[5.0 + d, 5.0]], [target], pursuer_policy="pure_pursuit", evader_policy="target",
            target=target, pursuer_speed=v,
        )[0]
        assert times[v] == k1 * dt
    assert abs(times[2.0] - times[1.0] / 2) <= dt


@pytest.mark.parametrize("ep", ["centroid", "constant_area", "area_max", "target"])
@pytest.mark.parametrize("pp", ["area_min", "pure_pursuit"])
def test_velocities_scale_with_team_speeds(pp, ep):
    """Every policy's control is its unit-speed control times its team's v_max."""
    rng = np.random.default_rng(5)
    P, E = rng.uniform(0, 10, (3, 2)), rng.uniform(0, 10, (2, 2))
    alive = np.array([True, True])
    kw = dict(pursuer_policy=pp, evader_policy=ep, target=(0.0, 5.0))
    up1, ue1 = reference_velocities(P, E, alive, **kw)
    up2, ue2 = reference_velocities(P, E, alive, pursuer_speed=2.5, evader_speed=0.4, **kw)
    np.testing.assert_allclose(np.linalg.norm(up1, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(ue1, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(up2, 2.5 * up1, atol=1e-12)
    np.testing.assert_allclose(ue2, 0.4 * ue1, atol=1e-12)


def test_target_evader_speed_capped_by_distance():
    """A `target` evader moves at min(evader_speed, distance / dt)."""
    kw = dict(pursuer_policy="pure_pursuit", evader_policy="target", target=(5.0, 5.02))
    _, u = reference_velocities([[0.5, 0.5]], [[5.0, 5.0]], [True], evader_speed=3.0, **kw)
    np.testing.assert_allclose(u, [[0.0, 2.0]], atol=1e-9)
    _, u = reference_velocities([[0.5, 0.5]], [[5.0, 5.0]], [True], evader_speed=1.5, **kw)
    np.testing.assert_allclose(u, [[0.0, 1.5]], atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(exit_point=(np.nan, 5.0)), "exit_point"),
        (dict(exit_point=(0.0, np.inf)), "exit_point"),
        (dict(exit_point=(1.0, 2.0, 3.0)), "exit_point"),
        (dict(exit_point="exit"), "exit_point"),
        (dict(pursuer_speed=0.0), "pursuer_speed"),
        (dict(pursuer_speed=np.nan), "pursuer_speed"),
        (dict(evader_speed=-1.0), "evader_speed"),
    ],
)
def test_reference_rejects_bad_exit_and_speeds(kwargs, name):
    with pytest.raises(ValueError, match=f"^{name}: "):
        reference_game([[1.0, 1.0]], [[9.0, 9.0]], t_max=0.1, **kwargs)
