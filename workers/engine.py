"""The pursuit-evasion engine, compiled (numba): each game stepped to its end on its own.

Semantics (docs/model.md sections 1-2): explicit Euler with fixed dt; at step k the controls
of every agent come from the state at k, then all agents move, then positions are projected
onto the arena. After the move, evader i is captured at t = (k+1) dt when its distance to the
nearest pursuer is below r_c (strictly); then, when the game has an exit point, a live evader
closer than r_c to it escapes at that time. Both are checked at t = 0 on the initial positions
too. A captured or escaped evader leaves the game at once (no motion, no cell, no longer a
target). A game ends when no evader is left, or after floor(t_max / dt) steps.

Why one game at a time: a game's cost is then its own (a single game costs what
one game of a batch costs), its numbers cannot depend on what else shares the
call, and no step waits on the slowest game of a batch. Parallelism belongs to
the farm: one process per core, each playing its shard's games.
"""

from __future__ import annotations

import math
import types
import warnings
from collections import namedtuple
from dataclasses import dataclass, field
from functools import cache

import numpy as np
from numba import njit

from workers.arena import Arena, make_arena
from workers.case import case_defaults, check_exit_point
from workers.errors import (
    CoarseStepWarning,
    InputError,
    all_numbers,
    exact,
    is_whole,
    not_a_number_hint,
    point,
    positive,
)
from workers.geometry import (
    NEIGHBOUR_EDGE_MIN,
    Cells,
    area_centroid,
    build_cell,
    build_grid,
    cell_capacity,
    voronoi_cells,
)
from workers.policies import Policy, Step, evader_velocity, get_evader_policy, get_pursuer_policy, pursuer_velocity
from workers.policies.registry import dispatch, is_builtin
from workers.version import ENGINE_VERSION

__all__ = ["ENGINE_VERSION", "GameResults", "simulate_games", "step_velocities", "checked_games",
           "estimated_game_seconds", "case_defaults", "V_MAX", "coarse_step_ratio", "warn_coarse_step"]

V_MAX = 1.0
MAX_STEPS = 10_000_000


@dataclass
class GameResults:
    """Outcome of B games.

    capture_times: (B, n_e) float64, NaN where not captured by t_max;
    capture_step: (B, n_e) int64, step index whose move captured the evader
    (capture_times = capture_step * dt), -1 where not captured;
    escape_times, escape_step: the same for escapes through the exit point (all
    NaN and -1 without one); steps: (B,) int64 steps simulated before the game
    ended. With record=True: pursuer_paths (T+1, B, n_p, 2) and evader_paths
    (T+1, B, n_e, 2) float64 positions at t = 0, dt, ..., T dt (a finished game
    keeps its last positions), and `cells_at` rebuilds every agent's cell.
    """

    capture_times: np.ndarray
    capture_step: np.ndarray
    steps: np.ndarray
    dt: float
    t_max: float
    capture_radius: float
    arena: Arena
    pursuer_policy: str
    evader_policy: str
    escape_times: np.ndarray | None = None
    escape_step: np.ndarray | None = None
    exit_point: tuple[float, float] | None = None
    pursuer_speed: float = V_MAX
    evader_speed: float = V_MAX
    pursuer_paths: np.ndarray | None = None
    evader_paths: np.ndarray | None = None
    engine_version: str = field(default=ENGINE_VERSION)

    @property
    def n_games(self) -> int:
        """B, the number of games."""
        return self.capture_times.shape[0]

    def alive_at(self, frame: int) -> np.ndarray:
        """(B, n_e) bool: evaders still in the game (neither captured nor escaped) at t = frame * dt."""
        gone = np.where(self.capture_step >= 0, self.capture_step, self.escape_step)
        return (gone < 0) | (gone > frame)

    def cells_at(self, frame: int, game: int) -> tuple[Cells, np.ndarray]:
        """Cells of all live agents of one game at t = frame * dt (needs record=True).

        Returns the Cells (pursuers first, then live evaders) and the agent index
        (n_cells,) int64 of each, evaders numbered from n_p. A frame past the end is the last
        recorded one; a negative frame or a game out of range is an InputError.
        """
        if self.pursuer_paths is None:
            raise InputError("cells_at: the games were simulated without record=True", field="cells_at")
        if not is_whole(frame) or frame < 0:
            raise InputError(f"cells_at: frame must be a whole number >= 0 (a step index), got {frame!r}",
                             field="cells_at")
        games = self.pursuer_paths.shape[1]
        if not is_whole(game) or not 0 <= game < games:
            raise InputError(f"cells_at: game must be a whole number from 0 to {games - 1}, got {game!r}",
                             field="cells_at")
        frame = min(frame, len(self.pursuer_paths) - 1)
        pursuers = self.pursuer_paths[frame, game]
        evaders = self.evader_paths[frame, game]
        alive = self.alive_at(frame)[game]
        points = np.concatenate([pursuers, evaders])[None]
        live = np.concatenate([np.ones(len(pursuers), dtype=bool), alive])[None]
        agents = np.flatnonzero(live[0])
        return voronoi_cells(points, live, np.zeros_like(agents), agents, self.arena), agents


# ---------------------------------------------------------------- compiled core
Work = namedtuple("Work", "xs ys cell_of start items px py pl wx wy wl s cand cd2")
Work.__doc__ = """Scratch arrays for building the cells of one game (see geometry.build_grid, build_cell)."""


@njit(cache=True)
def _work(n, cap):
    """Scratch for the cells of a game of n agents (cap vertex slots)."""
    return Work(np.empty(n), np.empty(n), np.empty(n, dtype=np.int64), np.empty(n + 2, dtype=np.int64),
                np.empty(n, dtype=np.int64), np.empty(cap), np.empty(cap), np.empty(cap, dtype=np.int64),
                np.empty(cap), np.empty(cap), np.empty(cap, dtype=np.int64), np.empty(cap),
                np.empty(n, dtype=np.int64), np.empty(n))


@njit(cache=True)
def _step_state(n_p, n_e, cap, target, dt, vp, ve):
    """A Step with fresh arrays for one game (positions and distances filled by the caller).

    The neighbour entries: the evaders' cells are faces of one planar subdivision of
    the arena, whose edges number at most 3 (n_p + n_e + k), each bounding two cells, so
    all cells together have at most 6 (n_p + n_e + k) edges; cap (>= 2 (n + k)) adds slack."""
    size = 6 * (n_p + n_e) + 2 * cap
    return Step(np.empty((n_p, 2)), np.empty((n_e, 2)), np.ones(n_e, dtype=np.bool_), np.empty((n_p, n_e)),
                target, dt, vp, ve, np.zeros(n_e), np.empty((n_e, 2)), np.zeros(n_e + 1, dtype=np.int64),
                np.empty(size, dtype=np.int64), np.empty(size), np.empty((size, 2)),
                np.full(n_p, -1, dtype=np.int64), np.empty((n_p, 2)))


@njit(cache=True, inline="always")
def _evader_cells(s, w, av):
    """Fill the Step's cell fields: every live evader's cell among all live agents."""
    P, E, alive = s.P, s.E, s.alive
    n_p, n_e = P.shape[0], E.shape[0]
    n = 0
    for j in range(n_p):
        w.xs[n], w.ys[n] = P[j, 0], P[j, 1]
        n += 1
    for i in range(n_e):
        if alive[i]:
            w.xs[n], w.ys[n] = E[i, 0], E[i, 1]
            n += 1
    grid = build_grid(w.xs, w.ys, n, w.cell_of, w.start, w.items)
    best = np.full(n_p, np.inf)
    for j in range(n_p):
        s.pn_i[j] = -1
    slot, t = n_p, 0
    for i in range(n_e):
        s.nb_start[i] = t
        if not alive[i]:
            continue
        m = build_cell(slot, w.xs, w.ys, n, grid, w.cell_of, w.start, w.items, av, w.px, w.py, w.pl,
                       w.wx, w.wy, w.wl, w.s, w.cand, w.cd2)
        slot += 1
        s.area[i], s.cen[i, 0], s.cen[i, 1] = area_centroid(w.px, w.py, m, E[i, 0], E[i, 1])
        for v in range(m):
            j = w.pl[v]
            if j < 0 or j >= n_p:
                continue
            u = v + 1 if v + 1 < m else 0
            length = math.hypot(w.px[u] - w.px[v], w.py[u] - w.py[v])
            if length <= NEIGHBOUR_EDGE_MIN:
                continue
            mx, my = 0.5 * (w.px[v] + w.px[u]), 0.5 * (w.py[v] + w.py[u])
            if t == s.nb_j.shape[0]:
                raise RuntimeError("more shared edges than a planar subdivision has")
            s.nb_j[t], s.nb_len[t], s.nb_mid[t, 0], s.nb_mid[t, 1] = j, length, mx, my
            t += 1
            if s.d2[j, i] < best[j]:
                best[j] = s.d2[j, i]
                s.pn_i[j], s.pn_mid[j, 0], s.pn_mid[j, 1] = i, mx, my
    s.nb_start[n_e] = t


@njit(cache=True, inline="always")
def _project(x, y, box, lo, hi, av, normals, offsets):
    """The nearest point of the arena to (x, y)."""
    if box:
        return min(max(x, lo[0]), hi[0]), min(max(y, lo[1]), hi[1])
    k = av.shape[0]
    inside = True
    for e in range(k):
        if x * normals[e, 0] + y * normals[e, 1] - offsets[e] > 0.0:
            inside = False
    if inside:
        return x, y
    best, fx, fy = np.inf, x, y
    for e in range(k):
        f = e + 1 if e + 1 < k else 0
        abx, aby = av[f, 0] - av[e, 0], av[f, 1] - av[e, 1]
        t = ((x - av[e, 0]) * abx + (y - av[e, 1]) * aby) / (abx * abx + aby * aby)
        t = min(max(t, 0.0), 1.0)
        gx, gy = av[e, 0] + t * abx, av[e, 1] + t * aby
        d2 = (gx - x) * (gx - x) + (gy - y) * (gy - y)
        if d2 < best:
            best, fx, fy = d2, gx, gy
    return fx, fy


@njit(cache=True, inline="always")
def _distances(s):
    """Squared pursuer-evader distances of the Step, inf for evaders out of the game."""
    for j in range(s.P.shape[0]):
        px, py = s.P[j, 0], s.P[j, 1]
        for i in range(s.E.shape[0]):
            dx, dy = px - s.E[i, 0], py - s.E[i, 1]
            s.d2[j, i] = dx * dx + dy * dy if s.alive[i] else np.inf


@njit(cache=True, inline="always")
def _controls(s, w, av, p_kind, e_kind, cells, up, ue):
    """This step's velocities: up (n_p, 2), ue (n_e, 2) float64 (zero for evaders out of the game)."""
    if cells:
        _evader_cells(s, w, av)
    for j in range(s.P.shape[0]):
        up[j, 0], up[j, 1] = pursuer_velocity(p_kind, j, s)
    for i in range(s.E.shape[0]):
        if s.alive[i]:
            ue[i, 0], ue[i, 1] = evader_velocity(e_kind, i, s)
        else:
            ue[i, 0], ue[i, 1] = 0.0, 0.0


@njit(cache=True, inline="always")
def _leave(s, step, r_c, has_exit, exit_xy, capture_step, escape_step):
    """Captures, then escapes, at `step` (distances fresh); returns the evaders left."""
    n_p, n_e = s.P.shape[0], s.E.shape[0]
    left = 0
    for i in range(n_e):
        if not s.alive[i]:
            continue
        near2 = np.inf
        for j in range(n_p):
            near2 = min(near2, s.d2[j, i])
        near = np.inf
        if near2 < (r_c * (1.0 + 1e-6)) ** 2:  # close: decide on the exact distance
            for j in range(n_p):
                near = min(near, math.hypot(s.P[j, 0] - s.E[i, 0], s.P[j, 1] - s.E[i, 1]))
        if near < r_c:
            capture_step[i] = step
        elif has_exit and math.hypot(s.E[i, 0] - exit_xy[0], s.E[i, 1] - exit_xy[1]) < r_c:
            escape_step[i] = step
        else:
            left += 1
            continue
        s.alive[i] = False
        for j in range(n_p):
            s.d2[j, i] = np.inf
    return left


@njit(cache=True)
def _play(P0, E0, p_kind, e_kind, cells, r_c, dt, n_steps, target, has_exit, exit_xy, vp, ve,
          box, lo, hi, av, normals, offsets, record, rec_p, rec_e, capture_step, escape_step, steps):
    """Play games P0 (B, n_p, 2), E0 (B, n_e, 2) to their ends, one after the other.

    Writes capture_step, escape_step (B, n_e) int64 (-1: never) and steps (B,)
    int64; with record, positions into rec_p (F, B, n_p, 2) and rec_e (F, B, n_e, 2).
    """
    n_games, n_p, n_e = P0.shape[0], P0.shape[1], E0.shape[1]
    cap = cell_capacity(n_p + n_e, av.shape[0])
    w = _work(n_p + n_e, cap)
    s = _step_state(n_p, n_e, cap, target, dt, vp, ve)
    up, ue = np.empty((n_p, 2)), np.empty((n_e, 2))
    for b in range(n_games):
        s.P[:] = P0[b]
        s.E[:] = E0[b]
        s.alive[:] = True
        capture_step[b, :] = -1
        escape_step[b, :] = -1
        _distances(s)
        left = _leave(s, 0, r_c, has_exit, exit_xy, capture_step[b], escape_step[b])
        if record:
            rec_p[0, b], rec_e[0, b] = s.P, s.E
        k = 0
        while left > 0 and k < n_steps:
            _controls(s, w, av, p_kind, e_kind, cells, up, ue)
            for j in range(n_p):
                s.P[j, 0], s.P[j, 1] = _project(s.P[j, 0] + dt * up[j, 0], s.P[j, 1] + dt * up[j, 1],
                                                box, lo, hi, av, normals, offsets)
            for i in range(n_e):
                if s.alive[i]:
                    s.E[i, 0], s.E[i, 1] = _project(s.E[i, 0] + dt * ue[i, 0], s.E[i, 1] + dt * ue[i, 1],
                                                    box, lo, hi, av, normals, offsets)
            _distances(s)
            k += 1
            left = _leave(s, k, r_c, has_exit, exit_xy, capture_step[b], escape_step[b])
            if record:
                rec_p[k, b], rec_e[k, b] = s.P, s.E
        steps[b] = k
        if record:
            for f in range(k + 1, rec_p.shape[0]):
                rec_p[f, b], rec_e[f, b] = s.P, s.E


@njit(cache=True)
def _step_velocities(P, E, alive, p_kind, e_kind, cells, target, dt, vp, ve, av):
    n_states, n_p, n_e = P.shape[0], P.shape[1], E.shape[1]
    cap = cell_capacity(n_p + n_e, av.shape[0])
    w = _work(n_p + n_e, cap)
    s = _step_state(n_p, n_e, cap, target, dt, vp, ve)
    up, ue = np.empty((n_states, n_p, 2)), np.empty((n_states, n_e, 2))
    for a in range(n_states):
        s.P[:], s.E[:], s.alive[:] = P[a], E[a], alive[a]
        _distances(s)
        _controls(s, w, av, p_kind, e_kind, cells, up[a], ue[a])
    return up, ue


def _uncached_copy(kernel, **names):
    """A fresh compiled copy of `kernel` (same options, no disk cache) whose globals `names`
    are replaced, e.g. the dispatch it inlines."""
    f = kernel.py_func
    copy = types.FunctionType(f.__code__, {**f.__globals__, **names}, f.__name__, f.__defaults__, f.__closure__)
    copy.__qualname__ = f.__qualname__
    return njit(**{k: v for k, v in kernel.targetoptions.items() if k != "nopython"})(copy)


@cache
def _kernels_with(pursuer_dispatch, evader_dispatch):
    """(_play, _step_velocities) compiled with these dispatches inlined, not cached on disk.

    numba finds a cached kernel by its file, qualified name and argument types, never by
    the functions it inlines: a cached copy would share (and overwrite) the built-in
    kernels' entries, so a registry other than the built-in one gets copies compiled in
    memory, once per process (Dispatcher.recompile would flush the shared cache)."""
    controls = _uncached_copy(_controls, pursuer_velocity=pursuer_dispatch, evader_velocity=evader_dispatch)
    return _uncached_copy(_play, _controls=controls), _uncached_copy(_step_velocities, _controls=controls)


def _kernels(pp: Policy, ep: Policy):
    """The compiled (_play, _step_velocities) for games of these policies: the cached kernels
    for built-in policies, else copies compiled for the registry as it is now."""
    if is_builtin(pp, "pursuer") and is_builtin(ep, "evader"):
        return _play, _step_velocities
    return _kernels_with(dispatch("pursuer"), dispatch("evader"))


# ---------------------------------------------------------------- Python API
def estimated_game_seconds(n_pursuers: int, n_evaders: int, pursuer_policy: str, evader_policy: str,
                           t_max: float, dt: float, pursuer_speed: float = V_MAX, evader_speed: float = V_MAX) -> float:
    """A rough single-core cost of one game, for sizing work (good to a factor of 2-3).

    The cost of a game-step: a constant, plus one per evader cell growing with the agents in
    the game, one per pursuer-evader pair and one per agent, the coefficients below fitted to
    the engine's timings (benchmarks/engine.py). The game's length: about 700 steps at equal
    speeds, longer with more evaders than pursuers (caught one after another) and with slower
    pursuers, at most t_max / dt."""
    cells = get_pursuer_policy(pursuer_policy).needs_cells or get_evader_policy(evader_policy).needs_cells
    agents = n_pursuers + n_evaders
    per_step = 0.2e-6 + cells * n_evaders * (0.6e-6 + 3e-9 * agents) + 2e-9 * n_pursuers * n_evaders + 20e-9 * agents
    steps = 700.0 * max(1.0, n_evaders / n_pursuers) * max(1.0, evader_speed / pursuer_speed) ** 2
    return min(t_max / dt, steps) * per_step


def _positions(name: str, value, arena: Arena) -> np.ndarray:
    try:
        if not all_numbers(value):  # numpy would read True as 1.0 and "1" as 1.0
            raise TypeError
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{name}: positions must be numbers of shape (B, n, 2){not_a_number_hint(value)}",
                         field=name) from None
    if a.ndim != 3 or a.shape[2] != 2:
        raise InputError(f"{name}: positions must have shape (B, n, 2), got {a.shape}", field=name)
    if a.shape[1] == 0:
        raise InputError(f"{name}: the team is empty (n = 0)", field=name)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name}: positions must be finite (found NaN or inf)", field=name)
    outside = ~arena.contains(a)
    if outside.any():
        b, i = np.argwhere(outside)[0]
        # Exact coordinates: rounded ones (10.0000001 as 10) may print a point inside the arena.
        raise InputError(f"{name}: agent {i} of game {b} at ({exact(a[b, i, 0])}, {exact(a[b, i, 1])}) "
                         "is outside the arena", field=name)
    return a


def _arena_arrays(arena: Arena):
    lo, hi = arena.vertices.min(axis=0), arena.vertices.max(axis=0)
    return (arena.is_axis_box, np.ascontiguousarray(lo), np.ascontiguousarray(hi), np.ascontiguousarray(arena.vertices),
            np.ascontiguousarray(arena.normals), np.ascontiguousarray(arena.offsets))


def coarse_step_ratio(speed: float, dt: float, capture_radius: float) -> float:
    """How many capture radii an agent of top speed `speed` moves in one step of dt."""
    return speed * dt / capture_radius


def warn_coarse_step(speed: float, dt: float, capture_radius: float, stacklevel: int = 1) -> None:
    """A CoarseStepWarning when an agent moves more than the capture radius in one step
    (speed x dt > capture_radius): a pursuer may then pass an evader between two steps, so
    captures come late or never (docs/results.md has an example). The paper's setting
    (speeds 1, dt 0.01, capture radius 0.25) moves 0.04 radii a step.
    stacklevel 1 attributes the warning to the line calling this function, 2 to its caller's."""
    ratio = coarse_step_ratio(speed, dt, capture_radius)
    if ratio > 1.0:
        warnings.warn(f"dt: agents move up to {ratio:.3g} capture radii per step (speed {speed:g} x dt {dt:g} / "
                      f"capture_radius {capture_radius:g}); captures may come late or be missed",
                      CoarseStepWarning, stacklevel=stacklevel + 1)


def step_velocities(pursuers, evaders, alive, *, pursuer_policy=None, evader_policy=None, dt=None, target=None,
                    arena=None, pursuer_speed=None, evader_speed=None):
    """One step's controls for A game states (no validation; for tests and tools).

    pursuers: (A, n_p, 2) float64, evaders: (A, n_e, 2) float64, alive: (A, n_e) bool
    evaders still in the game; a setting left None is workers.Case's default. Returns
    u_p: (A, n_p, 2) and u_e: (A, n_e, 2) float64, zero for evaders out of the game.
    """
    pursuer_policy, evader_policy, dt, target, pursuer_speed, evader_speed = case_defaults(
        pursuer_policy=pursuer_policy, evader_policy=evader_policy, dt=dt, target=target,
        pursuer_speed=pursuer_speed, evader_speed=evader_speed)
    pp, ep = get_pursuer_policy(pursuer_policy), get_evader_policy(evader_policy)
    arena = make_arena(arena)
    return _kernels(pp, ep)[1](
        np.ascontiguousarray(pursuers, dtype=np.float64), np.ascontiguousarray(evaders, dtype=np.float64),
        np.ascontiguousarray(alive, dtype=np.bool_), pp.kind, ep.kind, pp.needs_cells or ep.needs_cells,
        np.asarray(target, dtype=np.float64), float(dt), float(pursuer_speed), float(evader_speed),
        np.ascontiguousarray(arena.vertices))


def checked_games(pursuers, evaders, arena, capture_radius, dt, t_max, target):
    """The games' common arguments checked, as the engine uses them.

    A bad one raises a one-line InputError naming it. Returns (arena Arena, pursuers
    (B, n_p, 2), evaders (B, n_e, 2) float64, r_c, dt, t_max float, target (2,) float64,
    n_steps int)."""
    arena = make_arena(arena)
    p = _positions("pursuers", pursuers, arena)
    e = _positions("evaders", evaders, arena)
    if p.shape[0] != e.shape[0]:
        raise InputError(f"evaders: batch size {e.shape[0]} differs from pursuers' {p.shape[0]}", field="evaders")
    r_c = positive("capture_radius", capture_radius)
    dt = positive("dt", dt)
    t_max = positive("t_max", t_max)
    goal = point("target", target)
    steps = t_max / dt + 1e-9  # inf when t_max / dt overflows
    if steps < 1:
        raise InputError(f"t_max: {t_max} is shorter than one step dt={dt}", field="t_max")
    if not steps < MAX_STEPS + 1:
        raise InputError(f"t_max/dt: {steps:.4g} steps is more than the engine's limit of {MAX_STEPS}")
    n_steps = math.floor(steps)
    return arena, p, e, r_c, dt, t_max, goal, n_steps


def simulate_games(
    pursuers,
    evaders,
    *,
    pursuer_policy: str | None = None,
    evader_policy: str | None = None,
    capture_radius: float | None = None,
    dt: float | None = None,
    t_max: float | None = None,
    target=None,
    arena=None,
    record: bool = False,
    exit_point=None,
    pursuer_speed: float | None = None,
    evader_speed: float | None = None,
) -> GameResults:
    """Play B independent games to the end.

    pursuers: (B, n_p, 2) float64, evaders: (B, n_e, 2) float64 initial
    positions inside the arena; arena: None for the square [0, 10]^2, else the
    vertices (k, 2) of a convex polygon; exit_point: None (no escapes), or the
    point (x, y) an evader escapes through when within capture_radius of it;
    pursuer_speed, evader_speed: each team's top speed. A setting left None is
    workers.Case's default. Returns GameResults; a bad argument raises a one-line
    InputError naming it (numbers must be finite and never bools; the exit point must be in
    the arena). A step in which an agent may move more than capture_radius
    (max(pursuer_speed, evader_speed) * dt > capture_radius) gives one CoarseStepWarning.
    """
    pursuer_policy, evader_policy, capture_radius, dt, t_max, target, pursuer_speed, evader_speed = case_defaults(
        pursuer_policy=pursuer_policy, evader_policy=evader_policy, capture_radius=capture_radius, dt=dt,
        t_max=t_max, target=target, pursuer_speed=pursuer_speed, evader_speed=evader_speed)
    pp = get_pursuer_policy(pursuer_policy)
    ep = get_evader_policy(evader_policy)
    arena, p, e, r_c, dt, t_max, goal, n_steps = checked_games(pursuers, evaders, arena, capture_radius, dt, t_max,
                                                               target)
    vp = positive("pursuer_speed", pursuer_speed)
    ve = positive("evader_speed", evader_speed)
    exit_xy = np.zeros(2) if exit_point is None else point("exit_point", exit_point)
    if exit_point is not None:
        check_exit_point(exit_xy, arena)
    warn_coarse_step(max(vp, ve), dt, r_c, stacklevel=2)

    n_games, n_p, n_e = p.shape[0], p.shape[1], e.shape[1]
    capture_step = np.empty((n_games, n_e), dtype=np.int64)
    escape_step = np.empty((n_games, n_e), dtype=np.int64)
    steps = np.empty(n_games, dtype=np.int64)
    box, lo, hi, av, normals, offsets = _arena_arrays(arena)
    play_games = _kernels(pp, ep)[0]

    def play(frames: int):
        rec_p, rec_e = np.empty((frames, n_games, n_p, 2)), np.empty((frames, n_games, n_e, 2))
        play_games(p, e, pp.kind, ep.kind, pp.needs_cells or ep.needs_cells, r_c, dt, n_steps, goal,
              exit_point is not None, exit_xy, vp, ve, box, lo, hi, av, normals, offsets, frames > 0,
              rec_p, rec_e, capture_step, escape_step, steps)
        return rec_p, rec_e

    play(0)
    if record:  # the games again, now that their length is known
        paths_p, paths_e = play(int(steps.max(initial=0)) + 1)
    exit_xy = None if exit_point is None else (float(exit_xy[0]), float(exit_xy[1]))
    return GameResults(np.where(capture_step >= 0, capture_step * dt, np.nan), capture_step, steps, dt, t_max, r_c,
                       arena, pursuer_policy, evader_policy, np.where(escape_step >= 0, escape_step * dt, np.nan),
                       escape_step, exit_xy, vp, ve, paths_p if record else None, paths_e if record else None)
