"""Sanity checks of the slow reference implementation (workers/reference.py)."""

import math

import numpy as np
import pytest
import shapely

from workers.reference import reference_cells, reference_game, reference_velocities

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


def test_voronoi_game_runs_and_captures():
    times = reference_game(
        [[1.0, 1.0], [9.0, 1.0]],
        [[5.0, 8.0], [2.0, 6.0]],
        pursuer_policy="area_min",
        evader_policy="centroid",
        t_max=30.0,
    )
    assert times.shape == (2,)
    assert np.all(np.isfinite(times)) and np.all(times > 0)


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
