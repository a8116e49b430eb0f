"""Slow, obvious reference implementation of the Voronoi pursuit-evasion game.

One game at a time, plain Python loops, no batching.  It exists only to
validate the fast batched engine, so clarity wins over speed everywhere.

Contract (summary)
------------------
* Arena: convex polygon, vertices (k, 2) in counter-clockwise order
  (default: the square [0, 10]^2).
* Single integrators, speed <= v_max (``pursuer_speed`` for the pursuers,
  ``evader_speed`` for the evaders, both 1 by default), explicit Euler with
  step ``dt``: controls from the state at step k, every live agent moves
  ``x += dt * u``, then each position is projected onto the arena.
* After the move, a live evader is captured at ``t = (k + 1) * dt`` when its
  distance to the nearest pursuer is < ``capture_radius`` (strict).  Evaders
  within the radius before step 0 are captured at t = 0.  Captured evaders
  leave the game at once (no motion, no cell, not a target or neighbour).
* Escape (optional, ``exit_point``): after the capture check of a step, a
  live evader that was not captured and whose distance to the exit point is
  < ``capture_radius`` (strict) escapes at ``t = (k + 1) * dt`` and leaves the
  game exactly like a captured one.  At t = 0 the captures are checked first,
  then the escapes.  Capture wins a tie, so no evader is ever both.
* The game stops when every evader is captured or escaped, or after
  ``floor(t_max / dt + 1e-9)`` steps.  Uncaptured evaders get capture time
  NaN; evaders that never escaped get escape time NaN.

Voronoi cells
-------------
Cells are computed with ``scipy.spatial.Voronoi`` on the live points plus one
mirror image of each point per arena edge.  The mirror is taken across the
edge line pushed outwards by a small margin (see ``_MIRROR_MARGIN``); for a
point lying on the arena boundary the exact mirror would coincide with the
point itself, which Qhull cannot handle.  A pushed-out mirror is never closer
than its original to any point of the arena, so the diagram restricted to the
arena is still exact; the (bounded) regions of the original points are then
clipped to the arena polygon, and ridges between two original points are
clipped to the arena as well.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from scipy.spatial import Voronoi

__all__ = ["reference_cells", "reference_game", "reference_velocities"]

DEFAULT_ARENA = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])

PURSUER_POLICIES = ("pure_pursuit", "area_min")
EVADER_POLICIES = ("centroid", "constant_area", "target", "area_max")

_EDGE_MIN_LENGTH = 1e-9  # shared edges at most this long do not make neighbours
_HEADING_EPS = 1e-12  # headings shorter than this give zero velocity
_COINCIDENT_EPS = 1e-12  # agents closer than this share one Voronoi cell
_TARGET_EPS = 1e-9  # a `target` evader this close to its target stops
_MIRROR_MARGIN = 1e-2  # mirror offset beyond the edge line, times the arena diameter


# --------------------------------------------------------------------------
# Arena helpers
# --------------------------------------------------------------------------
def _arena_array(arena) -> np.ndarray:
    """Arena vertices as a (k, 2) float64 array, checked to be counter-clockwise."""
    a = DEFAULT_ARENA.copy() if arena is None else np.array(arena, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2 or a.shape[0] < 3:
        raise ValueError(f"arena must have shape (k >= 3, 2), got {a.shape}")
    signed_area2 = 0.0
    for i in range(len(a)):
        x0, y0 = a[i]
        x1, y1 = a[(i + 1) % len(a)]
        signed_area2 += x0 * y1 - x1 * y0
    if signed_area2 <= 0.0:
        raise ValueError("arena vertices must be in counter-clockwise order")
    return a


def _edges(arena: np.ndarray):
    """Yield (a, b) pairs of edge endpoints (floats) of the polygon."""
    k = len(arena)
    for i in range(k):
        ax, ay = float(arena[i, 0]), float(arena[i, 1])
        bx, by = float(arena[(i + 1) % k, 0]), float(arena[(i + 1) % k, 1])
        yield (ax, ay), (bx, by)


def _project(x: float, y: float, arena: np.ndarray) -> tuple[float, float]:
    """Nearest point of the (convex, CCW) arena polygon to (x, y).

    Points inside (or on the boundary) are returned unchanged.  Otherwise the
    nearest point over all edge segments is returned; for an interior segment
    parameter the point is projected orthogonally onto the edge line, which
    is exact for axis-aligned edges.
    """
    inside = True
    for (ax, ay), (bx, by) in _edges(arena):
        if (bx - ax) * (y - ay) - (by - ay) * (x - ax) < 0.0:
            inside = False
            break
    if inside:
        return x, y

    best = None
    best_d2 = math.inf
    for (ax, ay), (bx, by) in _edges(arena):
        ex, ey = bx - ax, by - ay
        t = ((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey)
        if t <= 0.0:
            px, py = ax, ay
        elif t >= 1.0:
            px, py = bx, by
        else:
            length = math.sqrt(ex * ex + ey * ey)
            nx, ny = ey / length, -ex / length  # outward unit normal (CCW polygon)
            s = (x - ax) * nx + (y - ay) * ny
            px, py = x - s * nx, y - s * ny
        d2 = (x - px) ** 2 + (y - py) ** 2
        if d2 < best_d2:
            best_d2 = d2
            best = (px, py)
    return best


def _clip_segment(p, q, arena: np.ndarray):
    """Clip segment p-q to the convex CCW arena (Cyrus-Beck).

    Returns (length, midpoint (2,) ndarray), or None if nothing is left.
    """
    t0, t1 = 0.0, 1.0
    dx, dy = q[0] - p[0], q[1] - p[1]
    for (ax, ay), (bx, by) in _edges(arena):
        ex, ey = bx - ax, by - ay
        # inside <=> f0 + t * df >= 0
        f0 = ex * (p[1] - ay) - ey * (p[0] - ax)
        df = ex * dy - ey * dx
        if df == 0.0:
            if f0 < 0.0:
                return None
            continue
        t = -f0 / df
        if df > 0.0:
            t0 = max(t0, t)
        else:
            t1 = min(t1, t)
        if t0 > t1:
            return None
    sx, sy = p[0] + t0 * dx, p[1] + t0 * dy
    ex_, ey_ = p[0] + t1 * dx, p[1] + t1 * dy
    length = math.sqrt((ex_ - sx) ** 2 + (ey_ - sy) ** 2)
    return length, np.array([(sx + ex_) / 2.0, (sy + ey_) / 2.0])


# --------------------------------------------------------------------------
# Voronoi cells
# --------------------------------------------------------------------------
def _mirrored_voronoi(pts: np.ndarray, arena: np.ndarray) -> Voronoi:
    """scipy Voronoi of pts (m, 2) followed by their pushed-out mirror images.

    Input rows 0..m-1 are the points themselves; their regions are bounded.
    """
    diameter = max(math.dist(a, b) for a in arena for b in arena)
    margin = _MIRROR_MARGIN * diameter
    voronoi_input = [p for p in pts]
    for (ax, ay), (bx, by) in _edges(arena):
        ex, ey = bx - ax, by - ay
        length = math.sqrt(ex * ex + ey * ey)
        nx, ny = ey / length, -ex / length  # outward unit normal
        for px, py in pts:
            depth = -((px - ax) * nx + (py - ay) * ny)  # >= 0 inside the arena
            shift = 2.0 * (depth + margin)
            voronoi_input.append(np.array([px + shift * nx, py + shift * ny]))
    return Voronoi(np.array(voronoi_input))


def reference_cells(points, arena=None) -> list[dict]:
    """Bounded Voronoi cells of ``points`` inside the arena.

    Parameters
    ----------
    points : (n, 2) float64, all live agents.
    arena : (k, 2) float64 CCW convex polygon, default the square [0, 10]^2.

    Returns
    -------
    list of n dicts with keys
        'polygon'  : shapely Polygon of the cell (clipped to the arena),
        'area'     : float,
        'centroid' : (2,) ndarray,
        'edges'    : {neighbour_index: (length, midpoint (2,) ndarray)} for
                     neighbours whose shared edge is longer than 1e-9.

    An agent within 1e-12 of an earlier agent is left out of the Voronoi
    input and gets (a copy of) the earlier agent's cell and neighbours;
    neighbour indices always refer to such representative (first) agents.
    The same is done when Qhull itself merges two nearly coincident agents
    into one region.  Accuracy is ~1e-13 for well separated agents, but
    degrades for agents closer than ~1e-6 (ill-conditioned Qhull vertices).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    arena = _arena_array(arena)
    n = len(pts)
    if n == 0:
        return []
    rep = _representatives(pts)
    unique, vor = _voronoi_of_representatives(pts, arena, rep)
    cells_u = _unique_cells(vor, len(unique), arena)
    _add_edges(vor, unique, cells_u, arena)
    return _cells_of_every_agent(rep, unique, cells_u)


def _representatives(pts) -> list[int]:
    """Representative of each agent: the first agent it coincides with (itself if none)."""
    n = len(pts)
    rep = list(range(n))
    for i in range(n):
        for j in range(i):
            if rep[j] == j and math.dist(pts[i], pts[j]) < _COINCIDENT_EPS:
                rep[i] = j
                break
    return rep


def _voronoi_of_representatives(pts, arena, rep: list[int]):
    """(unique, vor): the representative agents and the mirrored Voronoi diagram of their points.

    Qhull may still merge two distinct but nearly coincident points into one region; the later
    one is then treated as a duplicate as well (rep is updated in place) and the diagram redone."""
    n = len(pts)
    while True:
        unique = [i for i in range(n) if rep[i] == i]
        vor = _mirrored_voronoi(pts[unique], arena)
        first_with_region = {}
        merged = False
        for a in range(len(unique)):
            r = vor.point_region[a]
            if r in first_with_region:
                rep[unique[a]] = unique[first_with_region[r]]
                merged = True
            else:
                first_with_region[r] = a
        if not merged:
            return unique, vor


def _unique_cells(vor, m: int, arena) -> list[dict]:
    """The cells of the first m points of vor (the representatives), clipped to the arena, without
    their edges yet."""
    arena_poly = shapely.Polygon(arena)
    cells_u = []  # cells of the unique points, indexed like `unique`
    for a in range(m):
        region = vor.regions[vor.point_region[a]]
        if len(region) < 3 or -1 in region:
            raise RuntimeError("unbounded Voronoi region for an original point")
        raw = shapely.MultiPoint(vor.vertices[region]).convex_hull
        poly = raw.intersection(arena_poly)
        c = poly.centroid
        cells_u.append(
            {
                "polygon": poly,
                "area": float(poly.area),
                "centroid": np.array([c.x, c.y]),
                "edges": {},
            }
        )
    return cells_u


def _add_edges(vor, unique: list[int], cells_u: list[dict], arena) -> None:
    """Each representative's cell's shared edges longer than _EDGE_MIN_LENGTH, clipped to the
    arena: cells_u[a]["edges"][unique[b]] = (length, midpoint)."""
    m = len(unique)
    for (a, b), ridge in zip(vor.ridge_points, vor.ridge_vertices):
        if a >= m or b >= m:
            continue  # ridge involving a mirror point
        if -1 in ridge:
            raise RuntimeError("unbounded ridge between two original points")
        clipped = _clip_segment(vor.vertices[ridge[0]], vor.vertices[ridge[1]], arena)
        if clipped is None or clipped[0] <= _EDGE_MIN_LENGTH:
            continue
        length, mid = clipped
        cells_u[a]["edges"][unique[b]] = (length, mid)
        cells_u[b]["edges"][unique[a]] = (length, mid.copy())


def _cells_of_every_agent(rep: list[int], unique: list[int], cells_u: list[dict]) -> list[dict]:
    """Every agent's cell: its representative's (a copy for a duplicate agent)."""
    position = {i: a for a, i in enumerate(unique)}
    cells = []
    for i in range(len(rep)):
        r = i
        while rep[r] != r:  # follow the chain to the representative
            r = rep[r]
        base = cells_u[position[r]]
        if r == i:
            cells.append(base)
        else:
            cells.append(
                {
                    "polygon": base["polygon"],
                    "area": base["area"],
                    "centroid": base["centroid"].copy(),
                    "edges": {k: (L, mid.copy()) for k, (L, mid) in base["edges"].items()},
                }
            )
    return cells


# --------------------------------------------------------------------------
# Policies
# --------------------------------------------------------------------------
def _unit(hx: float, hy: float) -> np.ndarray:
    """Unit vector along (hx, hy); zero if the heading is shorter than 1e-12."""
    norm = math.sqrt(hx * hx + hy * hy)
    if norm < _HEADING_EPS:
        return np.zeros(2)
    return np.array([hx / norm, hy / norm])


def _dist(p, q) -> float:
    dx, dy = p[0] - q[0], p[1] - q[1]
    return math.sqrt(dx * dx + dy * dy)


def _speed(name: str, value) -> float:
    """A team's v_max as a float; must be positive and finite."""
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name}: must be positive and finite, got {value!r}")
    return v


def _exit(exit_point):
    """The exit point as a (2,) float64 array, or None for a game without escapes."""
    if exit_point is None:
        return None
    try:
        x = np.array(exit_point, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"exit_point: must be a finite point (x, y), got {exit_point!r}") from None
    if x.shape != (2,) or not (math.isfinite(x[0]) and math.isfinite(x[1])):
        raise ValueError(f"exit_point: must be a finite point (x, y), got {exit_point!r}")
    return x


def reference_velocities(
    pursuers,
    evaders,
    alive,
    *,
    pursuer_policy,
    evader_policy,
    dt=0.01,
    target=(0.0, 5.0),
    arena=None,
    pursuer_speed=1.0,
    evader_speed=1.0,
):
    """Controls of one step.

    Parameters
    ----------
    pursuers : (n_p, 2) float64 positions.
    evaders : (n_e, 2) float64 positions.
    alive : (n_e,) bool, True for evaders still in the game (neither
        captured nor escaped).
    pursuer_speed, evader_speed : float, each team's v_max: every policy
        heads at this speed (a `target` evader at min(evader_speed,
        distance / dt), so that it lands on its target).

    Returns
    -------
    u_p : (n_p, 2) float64 pursuer velocities.
    u_e : (n_e, 2) float64 evader velocities (zero for dead evaders).
    """
    if pursuer_policy not in PURSUER_POLICIES:
        raise ValueError(f"unknown pursuer policy {pursuer_policy!r}")
    if evader_policy not in EVADER_POLICIES:
        raise ValueError(f"unknown evader policy {evader_policy!r}")
    v_p = _speed("pursuer_speed", pursuer_speed)
    v_e = _speed("evader_speed", evader_speed)
    P = np.asarray(pursuers, dtype=np.float64).reshape(-1, 2)
    E = np.asarray(evaders, dtype=np.float64).reshape(-1, 2)
    alive = np.asarray(alive, dtype=bool).reshape(-1)
    n_p, n_e = len(P), len(E)
    live = [i for i in range(n_e) if alive[i]]
    u_p = np.zeros((n_p, 2))
    u_e = np.zeros((n_e, 2))
    if not live:
        return u_p, u_e

    # Voronoi input order: all pursuers, then the live evaders.
    # Global index g < n_p is pursuer g; g = n_p + a is evader live[a].
    cells = None
    needs_cells = pursuer_policy == "area_min" or evader_policy != "target"
    if needs_cells:
        cells = reference_cells(np.vstack([P, E[live]]), arena)
    for j in range(n_p):
        u_p[j] = v_p * _unit(*_pursuer_heading(j, P, E, live, cells, pursuer_policy))
    for a, i in enumerate(live):
        if evader_policy == "target":
            u = _target_velocity(E[i], target, v_e, dt)
        else:
            u = _evader_velocity(E[i], cells[n_p + a], P, evader_policy, v_e)
        if u is not None:
            u_e[i] = u
    return u_p, u_e


def _pursuer_heading(j, P, E, live, cells, pursuer_policy) -> tuple:
    """Pursuer j's heading (hx, hy): area_min heads for the midpoint of its edge shared with the
    nearest evader among its neighbours; pure pursuit (and area_min without an evader neighbour)
    heads for the nearest live evader."""
    n_p = len(P)
    if pursuer_policy == "area_min":
        best_e, best_d, best_mid = None, math.inf, None
        for g, (_, mid) in cells[j]["edges"].items():
            if g < n_p:  # a pursuer
                continue
            i = live[g - n_p]
            d = _dist(P[j], E[i])
            if d < best_d or (d == best_d and i < best_e):
                best_e, best_d, best_mid = i, d, mid
        if best_e is not None:
            return (best_mid[0] - P[j, 0], best_mid[1] - P[j, 1])
    best_e, best_d = None, math.inf
    for i in live:
        d = _dist(P[j], E[i])
        if d < best_d:  # strict: ties keep the lowest index
            best_e, best_d = i, d
    return (E[best_e, 0] - P[j, 0], E[best_e, 1] - P[j, 1])


def _target_velocity(x, target, v_e, dt):
    """A `target` evader's velocity at x: toward the target at min(v_e, distance / dt); None (no
    move) within _TARGET_EPS of it."""
    tx, ty = float(target[0]), float(target[1])
    hx, hy = tx - x[0], ty - x[1]
    dist = math.sqrt(hx * hx + hy * hy)
    if dist < _TARGET_EPS:
        return None
    speed = min(v_e, dist / dt)
    return np.array([hx / dist * speed, hy / dist * speed])


def _evader_velocity(x, cell, P, evader_policy, v_e):
    """The velocity of an evader at x with Voronoi cell `cell`: constant_area heads for the
    midpoint of its edge shared with the nearest pursuer, area_max along the edge-weighted sum of
    its pursuer edges' midpoints, centroid (and both others without a pursuer neighbour) for its
    cell's centroid."""
    n_p = len(P)
    pursuer_edges = {g: e for g, e in cell["edges"].items() if g < n_p}
    if evader_policy == "constant_area" and pursuer_edges:
        best_j, best_d, best_mid = None, math.inf, None
        for j, (_, mid) in pursuer_edges.items():
            d = _dist(P[j], x)
            if d < best_d or (d == best_d and j < best_j):
                best_j, best_d, best_mid = j, d, mid
        return v_e * _unit(best_mid[0] - x[0], best_mid[1] - x[1])
    if evader_policy == "area_max" and pursuer_edges:
        hx = hy = 0.0
        for j in sorted(pursuer_edges):
            length, mid = pursuer_edges[j]
            d = _dist(P[j], x)
            if d < _COINCIDENT_EPS:
                continue
            w = length / d
            hx += w * (mid[0] - x[0])
            hy += w * (mid[1] - x[1])
        return v_e * _unit(hx, hy)
    c = cell["centroid"]
    return v_e * _unit(c[0] - x[0], c[1] - x[1])


# --------------------------------------------------------------------------
# Game
# --------------------------------------------------------------------------
def _captured_now(e, P, capture_radius) -> bool:
    """True when evader position e (2,) is strictly within the radius of a pursuer."""
    return min(_dist(e, p) for p in P) < capture_radius if len(P) else False


def reference_game(
    pursuers,
    evaders,
    *,
    pursuer_policy="area_min",
    evader_policy="centroid",
    capture_radius=0.25,
    dt=0.01,
    t_max=60.0,
    target=(0.0, 5.0),
    arena=None,
    exit_point=None,
    pursuer_speed=1.0,
    evader_speed=1.0,
    return_escapes=False,
):
    """Play one game.

    Parameters
    ----------
    pursuers : (n_p, 2) float64 initial pursuer positions.
    evaders : (n_e, 2) float64 initial evader positions.
    exit_point : None (no escapes, the paper's game) or a finite point (x, y):
        a live evader that is not captured at a step and is then strictly
        within ``capture_radius`` of it escapes (leaves the game).
    pursuer_speed, evader_speed : float, each team's v_max (default 1).
    return_escapes : bool; when True return (capture_times, escape_times).

    Returns
    -------
    capture_times : (n_e,) float64, ``(k + 1) * dt`` for a capture after step
        k, 0.0 for an evader captured before step 0, NaN if never captured.
    escape_times : (n_e,) float64, only with ``return_escapes=True``: the same
        for escapes, NaN if the evader never escaped (always NaN without an
        exit point).
    """
    arena = _arena_array(arena)
    exit_xy = _exit(exit_point)
    _speed("pursuer_speed", pursuer_speed)
    _speed("evader_speed", evader_speed)
    P = np.array(pursuers, dtype=np.float64).reshape(-1, 2)
    E = np.array(evaders, dtype=np.float64).reshape(-1, 2)
    n_e = len(E)
    capture_times = np.full(n_e, np.nan)
    escape_times = np.full(n_e, np.nan)
    alive = np.ones(n_e, dtype=bool)

    def check_events(t):
        """Captures first, then escapes among the evaders still alive."""
        for i in range(n_e):
            if alive[i] and _captured_now(E[i], P, capture_radius):
                capture_times[i] = t
                alive[i] = False
        if exit_xy is not None:
            for i in range(n_e):
                if alive[i] and _dist(E[i], exit_xy) < capture_radius:
                    escape_times[i] = t
                    alive[i] = False

    check_events(0.0)

    n_steps = math.floor(t_max / dt + 1e-9)
    for k in range(n_steps):
        if not alive.any():
            break
        u_p, u_e = reference_velocities(
            P,
            E,
            alive,
            pursuer_policy=pursuer_policy,
            evader_policy=evader_policy,
            dt=dt,
            target=target,
            arena=arena,
            pursuer_speed=pursuer_speed,
            evader_speed=evader_speed,
        )
        for j in range(len(P)):
            x = P[j, 0] + dt * u_p[j, 0]
            y = P[j, 1] + dt * u_p[j, 1]
            P[j] = _project(x, y, arena)
        for i in range(n_e):
            if alive[i]:
                x = E[i, 0] + dt * u_e[i, 0]
                y = E[i, 1] + dt * u_e[i, 1]
                E[i] = _project(x, y, arena)
        check_events((k + 1) * dt)
    if return_escapes:
        return capture_times, escape_times
    return capture_times
