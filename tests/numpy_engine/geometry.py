"""Bounded Voronoi cells of many games at once, by half-plane clipping.

The cell of site p is the arena clipped by the bisector half-planes
{x : |x - p| <= |x - q|} of the other live agents q. Sites from all games are
clipped together, one half-plane per site per round, nearest agent first; a
site's cell is final once the next agent is farther than twice the cell's
radius (its bisector cannot reach the cell), and finished cells drop out.

Every edge of a cell carries the label of the agent whose bisector it lies on
(-1 - e for edge e of the arena), so shared edges with neighbours come for free.

Warm start: from one step to the next a cell's structure (the cyclic list of
lines its edges lie on) rarely changes. Given last step's labels as a hint, the
vertices are re-intersected from those lines in one vectorized pass and the
result is accepted only if it is provably the cell: the boundary turns left at
every vertex and once around in all, it has positive area, every edge has
non-negative length in counter-clockwise order, and every vertex is inside every
half-plane to the clipper's own tolerance (a convex polygon of winding one
bounded by the constraints' own lines that satisfies all constraints is their
intersection). Cells that fail are clipped from scratch.
Sums run left to right over the vertex axis (``cumsum``), so a cell's numbers do
not depend on how many other cells or how much padding share its batch.
"""

from __future__ import annotations

import numpy as np

from workers.arena import Arena
from workers.geometry import Cells  # the same container as the compiled engine's

__all__ = ["Cells", "voronoi_cells", "NEIGHBOUR_EDGE_MIN"]

NEIGHBOUR_EDGE_MIN = 1e-9
_COINCIDENT = 1e-12
_CLIP_TOL = 1e-12
PAD = -(1 << 40)  # label of padding slots


def _take_next(a: np.ndarray) -> np.ndarray:
    """Element i+1 along axis 1, wrapping; exact for padded polygons (see Cells)."""
    return np.concatenate([a[:, 1:], a[:, :1]], axis=1)


class _Polygons:
    """The growing polygons of voronoi_cells: x, y (C, M), count (C,), labels (C, M)."""

    def __init__(self, arena: Arena, n: int):
        k = arena.k
        self.x = np.repeat(arena.vertices[None, :, 0], n, axis=0)
        self.y = np.repeat(arena.vertices[None, :, 1], n, axis=0)
        self.count = np.full(n, k, dtype=np.int64)
        self.labels = np.repeat(-1 - np.arange(k, dtype=np.int64)[None], n, axis=0)

    def widen(self, m: int) -> None:
        pad = m - self.x.shape[1]
        if pad > 0:
            self.x = np.concatenate([self.x, np.repeat(self.x[:, :1], pad, axis=1)], axis=1)
            self.y = np.concatenate([self.y, np.repeat(self.y[:, :1], pad, axis=1)], axis=1)
            self.labels = np.concatenate([self.labels, np.full((len(self.x), pad), PAD, dtype=np.int64)], axis=1)


def voronoi_cells(
    points: np.ndarray,
    live: np.ndarray,
    site_game: np.ndarray,
    site_agent: np.ndarray,
    arena: Arena,
    hint: np.ndarray | None = None,
) -> Cells:
    """Bounded Voronoi cells of chosen sites among the live agents of each game.

    points: (B, n, 2) float64 agent positions; live: (B, n) bool agents that take
    part; site_game, site_agent: (C,) int64 which cells to build (each must be
    live); hint: optional (C, H) int64 labels of each site's cell at the last
    step (PAD-padded at the end; a row of PAD means none). Agents coincident with
    the site (closer than 1e-12) are ignored for its cell. Returns Cells of C
    sites, labels indexing the n agents.
    """
    site_game = np.asarray(site_game, dtype=np.int64)
    site_agent = np.asarray(site_agent, dtype=np.int64)
    n_cells = len(site_game)
    site = points[site_game, site_agent]  # (C, 2)
    if n_cells == 0:
        poly = _Polygons(arena, 0)
        return Cells(site, poly.x, poly.y, poly.count, poly.labels)

    ox = points[site_game, :, 0]  # (C, n)
    oy = points[site_game, :, 1]
    sx, sy = site[:, 0], site[:, 1]
    d2 = (ox - sx[:, None]) ** 2 + (oy - sy[:, None]) ** 2
    usable = live[site_game] & (d2 >= _COINCIDENT**2)
    d2 = np.where(usable, d2, np.inf)

    if hint is None:
        return _clip_cells(arena, site, ox, oy, d2)
    warm = _from_hint(arena, site, ox, oy, d2, np.asarray(hint, dtype=np.int64))
    ok = warm.count > 0
    if ok.all():
        return warm
    cold = _clip_cells(arena, site[~ok], ox[~ok], oy[~ok], d2[~ok])
    m = max(warm.x.shape[1], cold.x.shape[1])
    x, y, labels = (_pad_to(a, m) for a in (warm.x, warm.y, warm.labels))
    count = warm.count.copy()
    x[~ok], y[~ok], labels[~ok] = _pad_to(cold.x, m), _pad_to(cold.y, m), _pad_to(cold.labels, m)
    count[~ok] = cold.count
    return Cells(site, x, y, count, labels)


def _pad_to(a: np.ndarray, m: int) -> np.ndarray:
    """Widen (C, M) vertex coordinates (with copies of column 0) or labels (with PAD) to m columns."""
    pad = m - a.shape[1]
    if pad <= 0:
        return a.copy()
    fill = np.full((len(a), pad), PAD, dtype=a.dtype) if a.dtype == np.int64 else np.repeat(a[:, :1], pad, axis=1)
    return np.concatenate([a, fill], axis=1)


def _from_hint(arena: Arena, site, ox, oy, d2, hint) -> Cells:
    """Cells rebuilt from last step's structure; count 0 where the hint is not the cell."""
    count = np.count_nonzero(hint != PAD, axis=1)
    m = max(int(count.max()), 1)
    labels = hint[:, :m]
    n = ox.shape[1]
    # Constraint lines nx*x + ny*y <= off: the live agents' bisectors (C, n) (unit
    # normals, zero for unusable agents), then the arena's edges.
    px, py = site[:, 0, None], site[:, 1, None]
    usable = np.isfinite(d2)
    inv_norm = np.where(usable, 1.0 / np.sqrt(np.where(usable, d2, 1.0)), 0.0)
    ax, ay = (ox - px) * inv_norm, (oy - py) * inv_norm
    aoff = np.where(usable, 0.5 * (ox * ox + oy * oy - px * px - py * py) * inv_norm, 1.0)
    line = np.where(labels >= 0, labels, n - 1 - labels)
    line = np.where(labels == PAD, 0, line)
    line_usable = np.take_along_axis(usable, np.minimum(line, n - 1), axis=1) | (labels < 0)

    def pick(agent_values, arena_values):
        table = np.concatenate([agent_values, np.broadcast_to(arena_values, (len(site), arena.k))], axis=1)
        return np.take_along_axis(table, line, axis=1)

    nx, ny, off = pick(ax, arena.normals[:, 0]), pick(ay, arena.normals[:, 1]), pick(aoff, arena.offsets)
    slot = np.arange(m)
    valid = slot < count[:, None]
    prev = np.where(slot == 0, count[:, None] - 1, slot - 1)
    pnx, pny, poff = (np.take_along_axis(a, prev, axis=1) for a in (nx, ny, off))
    det = pnx * ny - pny * nx  # > 0: the boundary turns left at vertex i
    good_det = det > 1e-12
    det = np.where(good_det, det, 1.0)
    x = np.where(valid, (poff * ny - off * pny) / det, 0.0)
    y = np.where(valid, (pnx * off - nx * poff) / det, 0.0)
    x = np.where(valid, x, x[:, :1])
    y = np.where(valid, y, y[:, :1])
    ok = (count >= 3) & np.all(~valid | (good_det & line_usable), axis=1)
    # The normals turn left at every vertex and once around in all: a convex polygon of winding one.
    turning = np.where(valid, np.arctan2(det, pnx * nx + pny * ny), 0.0)
    ok &= np.abs(np.cumsum(turning, axis=1)[:, -1] - 2 * np.pi) < 1e-6

    # Every vertex inside every live agent's half-plane and the arena.
    s_agent = x[:, :, None] * ax[:, None, :] + y[:, :, None] * ay[:, None, :] - aoff[:, None, :]
    ok &= ~np.any(s_agent > _CLIP_TOL, axis=(1, 2))
    if arena.is_axis_box:
        (lo_x, lo_y), (hi_x, hi_y) = arena.vertices.min(axis=0), arena.vertices.max(axis=0)
        t = _CLIP_TOL
        ok &= np.all((x >= lo_x - t) & (x <= hi_x + t) & (y >= lo_y - t) & (y <= hi_y + t), axis=1)
    else:
        ok &= np.all(arena.signed_distances(np.stack([x, y], axis=-1)) <= _CLIP_TOL, axis=(1, 2))
    # Every edge runs counter-clockwise along its own line (non-negative length).
    xn, yn = _take_next(x), _take_next(y)
    along = (xn - x) * (-ny) + (yn - y) * nx
    ok &= np.all(~valid | (along >= -_CLIP_TOL), axis=1)
    # And it has an interior (three lines through one point pass every test above).
    cross = np.where(valid, (x - site[:, 0, None]) * (yn - site[:, 1, None])
                     - (xn - site[:, 0, None]) * (y - site[:, 1, None]), 0.0)
    ok &= np.cumsum(cross, axis=1)[:, -1] > 1e-18

    count = np.where(ok, count, 0)
    return Cells(site, x, y, count, np.where(valid, labels, PAD))


def _clip_cells(arena: Arena, site, ox, oy, d2) -> Cells:
    """Cells clipped from the arena, nearest agents first (see the module doc)."""
    n_cells = len(site)
    poly = _Polygons(arena, n_cells)
    order = np.argsort(d2, axis=1, kind="stable")
    d2_sorted = np.take_along_axis(d2, order, axis=1)
    sx, sy = site[:, 0], site[:, 1]
    active = np.arange(n_cells)
    for rank in range(ox.shape[1]):
        cand_d2 = d2_sorted[active, rank]
        if rank >= 2:  # the nearest agents nearly always cut: skip the test
            rx = poly.x[active] - sx[active, None]
            ry = poly.y[active] - sy[active, None]
            keep = cand_d2 < 4.0 * np.max(rx * rx + ry * ry, axis=1)  # also drops exhausted (inf) candidates
        else:
            keep = np.isfinite(cand_d2)
        if not keep.all():
            active = active[keep]
            if len(active) == 0:
                break
        agent = order[active, rank]
        rows = None if len(active) == n_cells else active
        _clip(poly, rows, sx[active], sy[active], ox[active, agent], oy[active, agent], agent)
    return Cells(site, poly.x, poly.y, poly.count, poly.labels)


def _clip(poly: _Polygons, rows, px, py, qx, qy, agent) -> None:
    """Clip the polygons `rows` by the half-planes closer to p than to q, in place.

    rows: (A,) int64, or None for all; px, py, qx, qy: (A,) float64; agent: (A,)
    int64 label of the new edge.
    """
    nx, ny = qx - px, qy - py
    norm = np.hypot(nx, ny)
    nx, ny = (nx / norm)[:, None], (ny / norm)[:, None]
    mx, my = (0.5 * (px + qx))[:, None], (0.5 * (py + qy))[:, None]
    x, y = (poly.x, poly.y) if rows is None else (poly.x[rows], poly.y[rows])
    s = (x - mx) * nx + (y - my) * ny
    inside = s <= _CLIP_TOL
    cut = ~np.all(inside, axis=1)
    if not cut.any():
        return
    if not cut.all():
        rows = np.flatnonzero(cut) if rows is None else rows[cut]
        x, y, s, inside, agent = x[cut], y[cut], s[cut], inside[cut], agent[cut]
    everything = rows is None
    if everything:
        rows = slice(None)
    cnt = poly.count[rows]
    lab = poly.labels[rows]
    valid = np.arange(x.shape[1]) < cnt[:, None]
    inside_next = _take_next(inside)
    exits = valid & inside & ~inside_next
    single_run = np.count_nonzero(exits, axis=1) == 1
    n_inside = np.count_nonzero(valid & inside, axis=1)
    poly.widen(int(np.where(single_run, n_inside + 2, 2 * cnt).max()))
    if single_run.all():
        _clip_run(poly, rows, x, y, s, valid, inside, inside_next, cnt, lab, agent, everything)
        return
    if everything:
        rows = np.arange(len(x))
    for f, clip in [(single_run, _clip_run), (~single_run, _clip_general)]:
        clip(poly, rows[f], x[f], y[f], s[f], valid[f], inside[f], inside_next[f], cnt[f], lab[f], agent[f])


def _clip_run(poly, rows, x, y, s, valid, inside, inside_next, cnt, lab, agent, everything=False) -> None:
    """Convex polygons whose inside vertices form one cyclic run (the usual case):
    the result is [entry point, the run, exit point], one gather, no scatter.
    everything: rows is slice(None), every polygon is replaced."""
    if len(x) == 0:
        return
    r = np.arange(len(x))
    i_out = np.argmax(valid & inside & ~inside_next, axis=1)
    i_in = np.argmax(valid & ~inside & inside_next, axis=1)
    i = np.concatenate([i_in, i_out])
    rr = np.concatenate([r, r])
    j = np.where(i + 1 < cnt[rr], i + 1, 0)
    sa, sb = s[rr, i], s[rr, j]
    t = np.clip(sa / (sa - sb), 0.0, 1.0)
    ex = x[rr, i] + t * (x[rr, j] - x[rr, i])  # entry points, then exit points
    ey = y[rr, i] + t * (y[rr, j] - y[rr, i])
    n, m = len(r), x.shape[1]
    # Gather from [vertices..., entry, exit]: slot 0 and the padding take the
    # entry point, then come the run of inside vertices and the exit point.
    ext_x = np.concatenate([x, ex[:n, None], ex[n:, None]], axis=1)
    ext_y = np.concatenate([y, ey[:n, None], ey[n:, None]], axis=1)
    ext_l = np.concatenate([lab, lab[r, i_in][:, None], agent[:, None]], axis=1)
    slot = np.arange(poly.x.shape[1])
    n_inside = np.count_nonzero(valid & inside, axis=1)
    last = (n_inside + 1)[:, None]
    src = np.where(slot < last, (i_in[:, None] + slot) % cnt[:, None], m)
    src[:, 0] = m
    src = np.where(slot == last, m + 1, src)
    new_x = np.take_along_axis(ext_x, src, axis=1)
    new_y = np.take_along_axis(ext_y, src, axis=1)
    new_l = np.where(slot > last, PAD, np.take_along_axis(ext_l, src, axis=1))
    if everything:
        poly.x, poly.y, poly.labels, poly.count = new_x, new_y, new_l, n_inside + 2
    else:
        poly.x[rows], poly.y[rows], poly.labels[rows], poly.count[rows] = new_x, new_y, new_l, n_inside + 2


def _clip_general(poly, rows, x, y, s, valid, inside, inside_next, cnt, lab, agent) -> None:
    """Sutherland-Hodgman with a scatter, for the rare polygons whose inside
    vertices (within the 1e-12 tolerance) do not form a single run."""
    if len(rows) == 0:
        return
    s_next = _take_next(s)
    emit_vertex = valid & inside
    emit_cross = valid & (inside != inside_next)
    t = np.clip(s / np.where(emit_cross, s - s_next, 1.0), 0.0, 1.0)
    cross_x = x + t * (_take_next(x) - x)
    cross_y = y + t * (_take_next(y) - y)
    cross_label = np.where(inside, agent[:, None], lab)
    n_emit = emit_vertex.astype(np.int64) + emit_cross
    end = np.cumsum(n_emit, axis=1)
    start = end - n_emit
    new_count = end[:, -1]
    m = poly.x.shape[1]
    out_x, out_y = np.empty((len(rows), m)), np.empty((len(rows), m))
    out_l = np.full((len(rows), m), PAD, dtype=np.int64)
    r, c = np.nonzero(emit_vertex)
    out_x[r, start[r, c]], out_y[r, start[r, c]], out_l[r, start[r, c]] = x[r, c], y[r, c], lab[r, c]
    r, c = np.nonzero(emit_cross)
    slot = start[r, c] + emit_vertex[r, c]
    out_x[r, slot], out_y[r, slot], out_l[r, slot] = cross_x[r, c], cross_y[r, c], cross_label[r, c]
    padding = np.arange(m) >= new_count[:, None]
    out_x = np.where(padding, out_x[:, :1], out_x)
    out_y = np.where(padding, out_y[:, :1], out_y)
    poly.x[rows], poly.y[rows], poly.labels[rows], poly.count[rows] = out_x, out_y, out_l, new_count
