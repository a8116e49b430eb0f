"""Bounded Voronoi cells, compiled (numba), one cell at a time.

The cell of site p is the arena clipped by the bisector half-planes
{x : |x - p| <= |x - q|} of the other live agents q. build_cell finds them (its docstring:
why its search may stop early) and clip clips by each (how edges are labelled).

Sums over a cell's vertices run in vertex order, so a cell's numbers depend only
on its own game.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from workers.arena import Arena

__all__ = ["Cells", "voronoi_cells", "NEIGHBOUR_EDGE_MIN"]

NEIGHBOUR_EDGE_MIN = 1e-9
COINCIDENT = 1e-12
CLIP_TOL = 1e-12
PAD = -(1 << 40)  # label of padding slots


@njit(cache=True)
def cell_capacity(n_agents, k):
    """Vertex slots a cell may need among n_agents agents in an arena of k edges.

    One per arena edge and agent, twice over for the rare clip whose inside vertices do
    not form one run (within the tolerance)."""
    return 2 * (n_agents + k) + 8


# ---------------------------------------------------------------- the grid
@njit(cache=True, inline="always")
def build_grid(xs, ys, n, cell_of, start, items):
    """Bucket n points into a G x G grid over their bounding box.

    xs, ys: (>= n,) float64 coordinates; cell_of: (>= n,) int64 out, each point's
    grid cell; start: (>= G*G + 1,) int64 out, items[start[c]:start[c+1]] are the
    points of cell c in index order; items: (>= n,) int64 out.
    Returns (G, x0, y0, inv_h, h): the grid's side, origin, 1/cell size, cell size.
    """
    g = max(1, int(math.sqrt(n / 2.0)))
    x0, x1, y0, y1 = xs[0], xs[0], ys[0], ys[0]
    for a in range(1, n):
        x0, x1 = min(x0, xs[a]), max(x1, xs[a])
        y0, y1 = min(y0, ys[a]), max(y1, ys[a])
    h = max(x1 - x0, y1 - y0, 1e-9) / g * (1.0 + 1e-12)
    inv_h = 1.0 / h
    for c in range(g * g + 1):
        start[c] = 0
    for a in range(n):
        cx = min(g - 1, int((xs[a] - x0) * inv_h))
        cy = min(g - 1, int((ys[a] - y0) * inv_h))
        cell_of[a] = cy * g + cx
        start[cell_of[a] + 1] += 1
    for c in range(g * g):
        start[c + 1] += start[c]
    fill = start[: g * g].copy()
    for a in range(n):
        items[fill[cell_of[a]]] = a
        fill[cell_of[a]] += 1
    return g, x0, y0, inv_h, h


# ---------------------------------------------------------------- one cell
@njit(cache=True, inline="always")
def _radius2(px, py, m, sx, sy):
    r2 = 0.0
    for v in range(m):
        d = (px[v] - sx) * (px[v] - sx) + (py[v] - sy) * (py[v] - sy)
        if d > r2:
            r2 = d
    return r2


@njit(cache=True, inline="always")
def clip(px, py, pl, m, sx, sy, qx, qy, label, wx, wy, wl, s):
    """Clip the polygon (px, py, pl)[:m] by the half-plane nearer to (sx, sy) than to (qx, qy).

    In place; the new edge takes `label`; wx, wy, wl, s are scratch of the same
    capacity. Returns (the new vertex count, whether anything was cut).

    Clipping a convex polygon by a half-plane keeps the vertices inside (signed distance s <=
    1e-12 to the bisector) and inserts the two crossing points, the entry point taking the label
    of the edge it lies on and the exit point the label of the clipping agent. Every edge
    carries the label of the agent whose bisector it lies on (-1 - e for edge e of the arena),
    so the edges shared with neighbours come for free.
    """
    nx, ny = qx - sx, qy - sy
    norm = math.hypot(nx, ny)
    nx, ny = nx / norm, ny / norm
    mx, my = 0.5 * (sx + qx), 0.5 * (sy + qy)
    outside = 0
    for v in range(m):
        s[v] = (px[v] - mx) * nx + (py[v] - my) * ny
        if s[v] > CLIP_TOL:
            outside += 1
    if outside == 0:
        return m, False
    # The exits (inside vertex, then outside) and entries (outside, then inside).
    exits, i_out, i_in = 0, -1, -1
    for v in range(m):
        w = v + 1 if v + 1 < m else 0
        a_in, b_in = s[v] <= CLIP_TOL, s[w] <= CLIP_TOL
        if a_in and not b_in:
            exits += 1
            i_out = v
        elif b_in and not a_in:
            i_in = v
    if exits == 0:  # nothing inside
        return 0, True
    if exits == 1:
        # [entry point, the run of inside vertices, exit point]
        w = i_in + 1 if i_in + 1 < m else 0
        t = min(max(s[i_in] / (s[i_in] - s[w]), 0.0), 1.0)
        wx[0] = px[i_in] + t * (px[w] - px[i_in])
        wy[0] = py[i_in] + t * (py[w] - py[i_in])
        wl[0] = pl[i_in]
        c = 1
        v = w
        while True:
            wx[c], wy[c], wl[c] = px[v], py[v], pl[v]
            c += 1
            if v == i_out:
                break
            v = v + 1 if v + 1 < m else 0
        w = i_out + 1 if i_out + 1 < m else 0
        t = min(max(s[i_out] / (s[i_out] - s[w]), 0.0), 1.0)
        wx[c] = px[i_out] + t * (px[w] - px[i_out])
        wy[c] = py[i_out] + t * (py[w] - py[i_out])
        wl[c] = label
        c += 1
    else:  # Sutherland-Hodgman, for inside vertices in several runs (within the tolerance)
        c = 0
        for v in range(m):
            w = v + 1 if v + 1 < m else 0
            a_in, b_in = s[v] <= CLIP_TOL, s[w] <= CLIP_TOL
            if a_in:
                wx[c], wy[c], wl[c] = px[v], py[v], pl[v]
                c += 1
            if a_in != b_in:
                t = min(max(s[v] / (s[v] - s[w]), 0.0), 1.0)
                wx[c] = px[v] + t * (px[w] - px[v])
                wy[c] = py[v] + t * (py[w] - py[v])
                wl[c] = label if a_in else pl[v]
                c += 1
    for v in range(c):
        px[v], py[v], pl[v] = wx[v], wy[v], wl[v]
    return c, True


@njit(cache=True, inline="always")
def build_cell(site, xs, ys, n, grid, cell_of, start, items, av, px, py, pl, wx, wy, wl, s, cand, cd2):
    """The Voronoi cell of point `site` among points 0..n-1, inside the arena.

    xs, ys: (>= n,) float64 points, bucketed by build_grid into grid =
    (G, x0, y0, inv_h, h), cell_of, start, items; av: (k, 2) float64 arena
    vertices, counter-clockwise; px, py: (M,) float64 out and pl: (M,) int64 out,
    the cell's vertices and edge labels (label of edge v, from vertex v to v+1:
    the point index across it, or -1 - e for arena edge e); wx, wy, wl, s: (M,)
    scratch; cand: (n,) int64 and cd2: (n,) float64 scratch. Returns the vertex count.

    The cell of site p is the arena clipped by the bisector half-planes of the other live agents
    q (clip; agents closer than 1e-12 to the site are ignored). Candidates q come from a uniform
    grid over the live agents' bounding box (about two agents per grid cell), visited ring by
    ring around the site's grid cell; within a ring they are clipped nearest first. A candidate
    farther than twice the cell's radius R (the largest distance from p to a vertex) cannot cut
    the cell: its bisector lies beyond R. The search stops once every agent not yet visited is
    that far: after ring r, an unvisited agent lies outside the block of rings 0..r, so at least
    as far from p as the nearest side of that block that is not the grid's own edge. So the cost
    of a cell is that of its few nearby agents, whatever the team sizes; with few agents the
    grid is one cell and this is plain nearest-first clipping.
    """
    g, x0, y0, inv_h, h = grid
    k = av.shape[0]
    for v in range(k):
        px[v], py[v], pl[v] = av[v, 0], av[v, 1], -1 - v
    m = k
    sx, sy = xs[site], ys[site]
    r2 = _radius2(px, py, m, sx, sy)
    cx, cy = cell_of[site] % g, cell_of[site] // g
    ring = 0
    while True:
        # This ring's candidates that can still cut, nearest first (ties: lower index).
        nc = 0
        for gy in range(max(0, cy - ring), min(g - 1, cy + ring) + 1):
            edge_row = gy == cy - ring or gy == cy + ring
            step = 1 if edge_row else 2 * ring
            gx = cx - ring
            while gx <= cx + ring:
                if 0 <= gx < g:
                    c = gy * g + gx
                    for t in range(start[c], start[c + 1]):
                        a = items[t]
                        d2 = (xs[a] - sx) * (xs[a] - sx) + (ys[a] - sy) * (ys[a] - sy)
                        if d2 >= COINCIDENT * COINCIDENT and d2 < 4.0 * r2:
                            u = nc
                            while u > 0 and (cd2[u - 1] > d2 or (cd2[u - 1] == d2 and cand[u - 1] > a)):
                                cand[u], cd2[u] = cand[u - 1], cd2[u - 1]
                                u -= 1
                            cand[u], cd2[u] = a, d2
                            nc += 1
                gx += step
        for u in range(nc):
            if cd2[u] >= 4.0 * r2:
                break
            a = cand[u]
            m, cut = clip(px, py, pl, m, sx, sy, xs[a], ys[a], a, wx, wy, wl, s)
            if cut:
                if m == 0:
                    return 0
                r2 = _radius2(px, py, m, sx, sy)
        # Unvisited points lie beyond the nearest side of the block that is not the grid's edge.
        lb = np.inf
        if cx - ring > 0:
            lb = min(lb, sx - (x0 + (cx - ring) * h))
        if cx + ring < g - 1:
            lb = min(lb, x0 + (cx + ring + 1) * h - sx)
        if cy - ring > 0:
            lb = min(lb, sy - (y0 + (cy - ring) * h))
        if cy + ring < g - 1:
            lb = min(lb, y0 + (cy + ring + 1) * h - sy)
        if lb == np.inf or lb * lb >= 4.0 * r2:
            return m
        ring += 1


@njit(cache=True, inline="always")
def area_centroid(px, py, m, sx, sy):
    """Area and centroid (shoelace about the site (sx, sy)) of the polygon (px, py)[:m]."""
    area2, cx, cy = 0.0, 0.0, 0.0
    for v in range(m):
        w = v + 1 if v + 1 < m else 0
        rx, ry = px[v] - sx, py[v] - sy
        rxn, ryn = px[w] - sx, py[w] - sy
        cross = rx * ryn - rxn * ry
        area2 += cross
        cx += cross * (rx + rxn)
        cy += cross * (ry + ryn)
    safe = area2 if area2 > 0 else 1.0
    return 0.5 * area2, sx + cx / (3.0 * safe), sy + cy / (3.0 * safe)


# ---------------------------------------------------------------- many cells, for plots and tests
@njit(cache=True)
def _cells_of_sites(points, live, site_game, site_agent, av, cap):
    n_sites, n = site_game.shape[0], points.shape[1]
    out_x = np.empty((n_sites, cap))
    out_y = np.empty((n_sites, cap))
    out_l = np.full((n_sites, cap), PAD, dtype=np.int64)
    count = np.zeros(n_sites, dtype=np.int64)
    xs, ys = np.empty(n), np.empty(n)
    index = np.empty(n, dtype=np.int64)  # compact slot -> agent
    cell_of, items = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    start = np.empty(n + 2, dtype=np.int64)
    px, py, wx, wy, s = np.empty(cap), np.empty(cap), np.empty(cap), np.empty(cap), np.empty(cap)
    pl, wl = np.empty(cap, dtype=np.int64), np.empty(cap, dtype=np.int64)
    cand, cd2 = np.empty(n, dtype=np.int64), np.empty(n)
    for c in range(n_sites):
        b = site_game[c]
        nl, site = 0, -1
        for a in range(n):
            if live[b, a]:
                if a == site_agent[c]:
                    site = nl
                xs[nl], ys[nl], index[nl] = points[b, a, 0], points[b, a, 1], a
                nl += 1
        grid = build_grid(xs, ys, nl, cell_of, start, items)
        m = build_cell(site, xs, ys, nl, grid, cell_of, start, items, av, px, py, pl, wx, wy, wl, s, cand, cd2)
        count[c] = m
        for v in range(cap):
            w = v if v < m else 0
            out_x[c, v], out_y[c, v] = px[w], py[w]
            if v < m:
                out_l[c, v] = index[pl[v]] if pl[v] >= 0 else pl[v]
    return out_x, out_y, count, out_l


@njit(cache=True)
def _area_centroid_many(x, y, count, site):
    n = x.shape[0]
    area, centroid = np.empty(n), np.empty((n, 2))
    for c in range(n):
        area[c], centroid[c, 0], centroid[c, 1] = area_centroid(x[c], y[c], count[c], site[c, 0], site[c, 1])
    return area, centroid


@dataclass
class Cells:
    """Convex cells of C sites, vertices counter-clockwise, padded to M.

    site: (C, 2) float64 generator position; x, y: (C, M) float64 vertex
    coordinates, the padding slots holding copies of vertex 0 (so padding edges
    have zero length); count: (C,) int64 number of valid vertices; labels: (C, M)
    int64, label of edge i (from vertex i to vertex i+1): the agent index on its
    other side, -1 - e for edge e of the arena, PAD in the padding.
    """

    site: np.ndarray
    x: np.ndarray
    y: np.ndarray
    count: np.ndarray
    labels: np.ndarray

    @property
    def vertices(self) -> np.ndarray:
        """(C, M, 2) float64."""
        return np.stack([self.x, self.y], axis=-1)

    @property
    def valid(self) -> np.ndarray:
        """(C, M) bool: vertex/edge slot i is in use."""
        return np.arange(self.x.shape[1]) < self.count[:, None]

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Edge lengths (C, M) float64 (0 in the padding) and midpoints (C, M, 2) float64."""
        slot = np.arange(self.x.shape[1])
        nxt = np.where(slot[None, :] + 1 < self.count[:, None], slot[None, :] + 1, 0)
        xn, yn = np.take_along_axis(self.x, nxt, axis=1), np.take_along_axis(self.y, nxt, axis=1)
        length = np.where(self.valid, np.hypot(xn - self.x, yn - self.y), 0.0)
        return length, np.stack([0.5 * (self.x + xn), 0.5 * (self.y + yn)], axis=-1)

    def area_centroid(self) -> tuple[np.ndarray, np.ndarray]:
        """Area (C,) float64 and centroid (C, 2) float64, as the engine computes them."""
        return _area_centroid_many(self.x, self.y, self.count, self.site)


def voronoi_cells(points, live, site_game, site_agent, arena: Arena) -> Cells:
    """Bounded Voronoi cells of chosen sites among the live agents of each game.

    points: (B, n, 2) float64 agent positions; live: (B, n) bool agents that take
    part; site_game, site_agent: (C,) int64 which cells to build (each must be
    live). Returns Cells of C sites, labels indexing the n agents.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    live = np.ascontiguousarray(live, dtype=np.bool_)
    site_game = np.ascontiguousarray(site_game, dtype=np.int64)
    site_agent = np.ascontiguousarray(site_agent, dtype=np.int64)
    cap = cell_capacity(points.shape[1], arena.k)
    x, y, count, labels = _cells_of_sites(points, live, site_game, site_agent, np.ascontiguousarray(arena.vertices), cap)
    return Cells(points[site_game, site_agent], x, y, count, labels)
