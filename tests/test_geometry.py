"""Cells of the batched clipper against scipy's Voronoi (tests/shapely_reference.py) and invariants."""

import numpy as np
import pytest
from conftest import HEXAGON, SQUARE, TRIANGLE, points_in
from shapely_reference import reference_cells

from workers import make_arena, voronoi_cells
from workers.geometry import NEIGHBOUR_EDGE_MIN


def all_cells(points, arena):
    b, n = points.shape[:2]
    live = np.ones((b, n), dtype=bool)
    g, a = np.nonzero(live)
    return voronoi_cells(points, live, g, a, make_arena(arena))


@pytest.mark.parametrize("arena", [SQUARE, HEXAGON, TRIANGLE], ids=["square", "hexagon", "triangle"])
def test_cells_match_scipy_voronoi(arena, rng):
    for n in (2, 3, 7, 25, 60):
        pts = points_in(arena, (3, n), rng)
        cells = all_cells(pts, arena)
        area, centroid = cells.area_centroid()
        length, mid = cells.edges()
        for b in range(3):
            ref = reference_cells(pts[b], arena)
            for i in range(n):
                c = b * n + i
                assert area[c] == pytest.approx(ref[i]["area"], abs=1e-9)
                np.testing.assert_allclose(centroid[c], ref[i]["centroid"], atol=1e-9)
                mine = {
                    int(cells.labels[c, s]): (length[c, s], mid[c, s])
                    for s in range(cells.count[c])
                    if cells.labels[c, s] >= 0 and length[c, s] > NEIGHBOUR_EDGE_MIN
                }
                assert set(mine) == set(ref[i]["edges"])
                for j, (L, m) in mine.items():
                    assert L == pytest.approx(ref[i]["edges"][j][0], abs=1e-9)
                    np.testing.assert_allclose(m, ref[i]["edges"][j][1], atol=1e-9)


@pytest.mark.parametrize("arena", [SQUARE, HEXAGON, TRIANGLE], ids=["square", "hexagon", "triangle"])
def test_cells_partition_the_arena(arena, rng):
    pts = points_in(arena, (20, 15), rng)
    area, centroid = all_cells(pts, arena).area_centroid()
    np.testing.assert_allclose(area.reshape(20, 15).sum(axis=1), make_arena(arena).area, rtol=1e-12)
    assert make_arena(arena).contains(centroid).all()


def test_shared_edges_are_symmetric(rng):
    pts = rng.random((1, 12, 2)) * 10
    cells = all_cells(pts, None)
    length, mid = cells.edges()
    edges = {}
    for c in range(12):
        for s in range(cells.count[c]):
            j = int(cells.labels[c, s])
            if j >= 0 and length[c, s] > NEIGHBOUR_EDGE_MIN:
                edges[(c, j)] = (length[c, s], mid[c, s])
    assert edges
    for (i, j), (L, m) in edges.items():
        L2, m2 = edges[(j, i)]
        assert L == pytest.approx(L2, abs=1e-12)
        np.testing.assert_allclose(m, m2, atol=1e-12)


def test_two_agents_analytic():
    cells = all_cells(np.array([[[2.0, 5.0], [8.0, 5.0]]]), None)
    area, centroid = cells.area_centroid()
    np.testing.assert_allclose(area, [50.0, 50.0])
    np.testing.assert_allclose(centroid, [[2.5, 5.0], [7.5, 5.0]])
    length, mid = cells.edges()
    s = list(cells.labels[0, : cells.count[0]]).index(1)
    assert length[0, s] == pytest.approx(10.0)
    np.testing.assert_allclose(mid[0, s], [5.0, 5.0])


def test_coincident_and_boundary_agents():
    """Coincident agents ignore each other, so each pair gets one and the same cell, and one
    agent of each pair with the others tiles the arena; agents on the boundary get cells too."""
    pts = np.array([[[0.0, 0.0], [0.0, 0.0], [10.0, 5.0], [5.0, 5.0], [5.0, 5.0], [0.0, 7.0]]])
    cells = all_cells(pts, None)
    area, centroid = cells.area_centroid()
    length, mid = cells.edges()
    assert np.all(np.isfinite(length)) and np.all(area > 0)
    assert area[0] == area[1] and area[3] == area[4]
    np.testing.assert_array_equal(centroid[0], centroid[1])
    np.testing.assert_array_equal(centroid[3], centroid[4])
    assert area[[0, 2, 3, 5]].sum() == pytest.approx(100.0, abs=1e-9)
    assert area[2] == pytest.approx(25.0)  # (10, 5) against (5, 5): the strip x >= 7.5
    np.testing.assert_allclose(centroid[2], [8.75, 5.0])


def test_batch_composition_does_not_change_a_cell(rng):
    """A cell's numbers are bit-identical whether it is built alone or among others."""
    pts = rng.random((6, 9, 2)) * 10
    together = all_cells(pts, None).area_centroid()
    for b in range(6):
        alone = all_cells(pts[b : b + 1], None).area_centroid()
        assert np.array_equal(alone[0], together[0][b * 9 : (b + 1) * 9])
        assert np.array_equal(alone[1], together[1][b * 9 : (b + 1) * 9])


