"""Cells of the batched clipper against scipy's Voronoi (workers.reference) and invariants."""

import numpy as np
import pytest

from conftest import HEXAGON, SQUARE, TRIANGLE, points_in
from workers import make_arena, voronoi_cells
from workers.geometry import NEIGHBOUR_EDGE_MIN
from workers.reference import reference_cells


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


def test_coincident_and_boundary_agents_give_no_nan():
    pts = np.array([[[0.0, 0.0], [0.0, 0.0], [10.0, 5.0], [5.0, 5.0], [5.0, 5.0], [0.0, 7.0]]])
    cells = all_cells(pts, None)
    area, centroid = cells.area_centroid()
    length, mid = cells.edges()
    assert np.all(np.isfinite(area)) and np.all(np.isfinite(centroid))
    assert np.all(np.isfinite(length)) and np.all(area > 0)


def test_batch_composition_does_not_change_a_cell(rng):
    """A cell's numbers are bit-identical whether it is built alone or among others."""
    pts = rng.random((6, 9, 2)) * 10
    together = all_cells(pts, None).area_centroid()
    for b in range(6):
        alone = all_cells(pts[b : b + 1], None).area_centroid()
        assert np.array_equal(alone[0], together[0][b * 9 : (b + 1) * 9])
        assert np.array_equal(alone[1], together[1][b * 9 : (b + 1) * 9])


def test_warm_start_from_last_steps_structure_equals_clipping(rng):
    """Cells rebuilt from a hint (last step's labels) equal cells clipped from scratch,
    and a hint that no longer fits (a new neighbour, a dead agent) is rejected."""
    from workers import DEFAULT_ARENA

    pts = rng.random((40, 8, 2)) * 10
    live = np.ones((40, 8), dtype=bool)
    g, a = np.nonzero(live)
    before = voronoi_cells(pts, live, g, a, DEFAULT_ARENA)
    moved = np.clip(pts + rng.normal(scale=0.01, size=pts.shape), 0, 10)
    live[0, 3] = False  # agent 3 of game 0 leaves: cells that named it must be rebuilt
    keep = live[g, a]
    g, a, hint = g[keep], a[keep], before.labels[keep]
    warm = voronoi_cells(moved, live, g, a, DEFAULT_ARENA, hint=hint)
    cold = voronoi_cells(moved, live, g, a, DEFAULT_ARENA)
    wa, wc = warm.area_centroid()
    ca, cc = cold.area_centroid()
    np.testing.assert_allclose(wa, ca, atol=1e-9)
    np.testing.assert_allclose(wc, cc, atol=1e-9)
    from workers.geometry import _from_hint

    d2 = ((moved[g] - moved[g, a][:, None]) ** 2).sum(-1)
    d2 = np.where(live[g] & (d2 > 0), d2, np.inf)
    accepted = _from_hint(DEFAULT_ARENA, moved[g, a], moved[g][..., 0], moved[g][..., 1], d2, hint).count > 0
    names_dead = (g == 0) & np.any(hint == 3, axis=1)
    assert names_dead.any() and not accepted[names_dead].any()
    assert accepted.mean() > 0.7
    for c in range(len(g)):
        wl, cl = warm.edges()[0][c], cold.edges()[0][c]
        w = {int(l): L for l, L in zip(warm.labels[c], wl) if l >= 0 and L > NEIGHBOUR_EDGE_MIN}
        k = {int(l): L for l, L in zip(cold.labels[c], cl) if l >= 0 and L > NEIGHBOUR_EDGE_MIN}
        assert w.keys() == k.keys()
        assert 3 not in w or g[c] != 0


def test_warm_start_rejects_hints_that_are_not_the_cell():
    """Three lines through one point pass the vertex and edge tests but enclose
    nothing; a cut deeper than the clipper's tolerance must not be ignored."""
    from workers import DEFAULT_ARENA
    from workers.geometry import _from_hint

    p = np.array([5.0, 5.0])
    angles = [-0.3, 0.0, 0.3]
    others = np.array([p + 2.0 * np.array([np.cos(a), np.sin(a)]) / np.cos(a) for a in angles])
    pts = np.vstack([p, others])[None]
    d2 = ((pts[0] - p) ** 2).sum(axis=1)[None]
    d2[0, 0] = np.inf
    hint = np.array([[1, 2, 3]])
    assert _from_hint(DEFAULT_ARENA, pts[0, :1], pts[..., 0], pts[..., 1], d2, hint).count[0] == 0
    live = np.ones((1, 4), dtype=bool)
    warm = voronoi_cells(pts, live, np.array([0]), np.array([0]), DEFAULT_ARENA, hint=hint)
    cold = voronoi_cells(pts, live, np.array([0]), np.array([0]), DEFAULT_ARENA)
    assert warm.area_centroid()[0][0] == pytest.approx(cold.area_centroid()[0][0])
    assert cold.area_centroid()[0][0] > 1.0

    # q3's bisector cuts the tip of the cell by 5e-11: an edge of about 1e-8, so a neighbour.
    a = 0.01
    q1, q2 = p + 2 * np.array([np.cos(a), np.sin(a)]), p + 2 * np.array([np.cos(a), -np.sin(a)])
    tip = p[0] + 1 / np.cos(a)
    q3 = np.array([2 * (tip - 5e-11) - p[0], p[1]])
    before = np.array([[p, q1, q2, [0.5, 0.5]]])
    live = np.array([[True, True, True, False]])
    hint = voronoi_cells(before, live, np.array([0]), np.array([0]), DEFAULT_ARENA).labels
    after = np.array([[p, q1, q2, q3]])
    live[0, 3] = True
    warm = voronoi_cells(after, live, np.array([0]), np.array([0]), DEFAULT_ARENA, hint=hint)
    length = warm.edges()[0][0]
    assert np.any((warm.labels[0] == 3) & (length > NEIGHBOUR_EDGE_MIN))
