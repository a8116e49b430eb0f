"""The batched pursuit-evasion engine: B games of the same team sizes and policies
stepped together; finished games drop out by mask.

Semantics (SPEC.md section 1): explicit Euler with fixed dt; at step k the
controls of every agent come from the state at k, then all agents move, then
positions are projected onto the arena; evader i is captured at t = (k+1) dt
when its distance to the nearest pursuer is below r_c (strictly), or at t = 0 if
it starts that close; captured evaders leave the game at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from workers.arena import Arena, make_arena
from workers.errors import InputError
from numpy_engine.geometry import PAD, Cells, voronoi_cells
from numpy_engine.policies import StepContext, get_evader_policy, get_pursuer_policy
from numpy_engine.policies.context import pursuer_evader_distance

__all__ = ["ENGINE_VERSION", "GameResults", "simulate_games", "V_MAX"]

ENGINE_VERSION = "1.1.0"
V_MAX = 1.0
MAX_STEPS = 10_000_000


@dataclass
class GameResults:
    """Outcome of B games.

    capture_times: (B, n_e) float64, NaN where not captured by t_max;
    capture_step: (B, n_e) int64, step index whose move captured the evader
    (capture_times = capture_step * dt), -1 where not captured;
    steps: (B,) int64 steps simulated before the game ended.
    With record=True: pursuer_paths (T+1, B, n_p, 2) and evader_paths
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
    pursuer_paths: np.ndarray | None = None
    evader_paths: np.ndarray | None = None
    engine_version: str = field(default=ENGINE_VERSION)

    @property
    def n_games(self) -> int:
        return self.capture_times.shape[0]

    def alive_at(self, frame: int) -> np.ndarray:
        """(B, n_e) bool: evaders still in the game at t = frame * dt."""
        return (self.capture_step < 0) | (self.capture_step > frame)

    def cells_at(self, frame: int, game: int) -> tuple[Cells, np.ndarray]:
        """Cells of all live agents of one game at t = frame * dt (needs record=True).

        Returns the Cells (pursuers first, then live evaders) and the agent index
        (n_cells,) int64 of each, evaders numbered from n_p.
        """
        if self.pursuer_paths is None:
            raise InputError("cells_at: the games were simulated without record=True")
        frame = min(frame, len(self.pursuer_paths) - 1)
        pursuers = self.pursuer_paths[frame, game]
        evaders = self.evader_paths[frame, game]
        alive = self.alive_at(frame)[game]
        points = np.concatenate([pursuers, evaders])[None]
        live = np.concatenate([np.ones(len(pursuers), dtype=bool), alive])[None]
        agents = np.flatnonzero(live[0])
        return voronoi_cells(points, live, np.zeros_like(agents), agents, self.arena), agents


def _positions(name: str, value, arena: Arena) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: positions must be numbers of shape (B, n, 2)") from None
    if a.ndim != 3 or a.shape[2] != 2:
        raise InputError(f"{name}: positions must have shape (B, n, 2), got {a.shape}")
    if a.shape[1] == 0:
        raise InputError(f"{name}: the team is empty (n = 0)")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name}: positions must be finite (found NaN or inf)")
    outside = ~arena.contains(a)
    if outside.any():
        b, i = np.argwhere(outside)[0]
        raise InputError(f"{name}: agent {i} of game {b} at ({a[b, i, 0]:g}, {a[b, i, 1]:g}) is outside the arena")
    return a


def _positive(name: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: must be a number, got {value!r}") from None
    if not np.isfinite(x) or x <= 0:
        raise InputError(f"{name}: must be positive and finite, got {value!r}")
    return x


def step_velocities(pursuers, evaders, alive, *, pursuer_policy="area_min", evader_policy="centroid",
                    dt=0.01, target=(0.0, 5.0), arena=None):
    """One step's controls for A game states (no validation; for tests and tools).

    pursuers (A, n_p, 2), evaders (A, n_e, 2) float64, alive (A, n_e) bool ->
    (u_p (A, n_p, 2), u_e (A, n_e, 2)) float64, zero for captured evaders.
    """
    ctx = StepContext(np.asarray(pursuers, dtype=np.float64), np.asarray(evaders, dtype=np.float64),
                      np.asarray(alive, dtype=bool), arena=make_arena(arena), dt=dt, v_max=V_MAX,
                      target=np.asarray(target, dtype=np.float64))
    u_p = get_pursuer_policy(pursuer_policy)(ctx)
    u_e = np.where(ctx.alive[..., None], get_evader_policy(evader_policy)(ctx), 0.0)
    return u_p, u_e


def simulate_games(
    pursuers,
    evaders,
    *,
    pursuer_policy: str = "area_min",
    evader_policy: str = "centroid",
    capture_radius: float = 0.25,
    dt: float = 0.01,
    t_max: float = 60.0,
    target=(0.0, 5.0),
    arena=None,
    record: bool = False,
) -> GameResults:
    """Play B independent games to the end.

    pursuers: (B, n_p, 2) float64, evaders: (B, n_e, 2) float64 initial
    positions inside the arena; arena: None for the square [0, 10]^2, else the
    vertices (k, 2) of a convex polygon. Returns GameResults.
    """
    arena = make_arena(arena)
    p_fn = get_pursuer_policy(pursuer_policy)
    e_fn = get_evader_policy(evader_policy)
    p = _positions("pursuers", pursuers, arena)
    e = _positions("evaders", evaders, arena)
    if p.shape[0] != e.shape[0]:
        raise InputError(f"evaders: batch size {e.shape[0]} differs from pursuers' {p.shape[0]}")
    r_c = _positive("capture_radius", capture_radius)
    dt = _positive("dt", dt)
    t_max = _positive("t_max", t_max)
    try:
        goal = np.array(target, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"target: must be a point (x, y), got {target!r}") from None
    if goal.shape != (2,) or not np.all(np.isfinite(goal)):
        raise InputError(f"target: must be a finite point (x, y), got {target!r}")
    n_steps = math.floor(t_max / dt + 1e-9)
    if n_steps < 1:
        raise InputError(f"t_max: {t_max} is shorter than one step dt={dt}")
    if n_steps > MAX_STEPS:
        raise InputError(f"t_max/dt: {n_steps} steps is more than the engine's limit of {MAX_STEPS}")

    n_games, n_e = e.shape[0], e.shape[1]
    capture_step = np.full((n_games, n_e), -1, dtype=np.int64)
    alive = np.ones((n_games, n_e), dtype=bool)
    steps = np.zeros(n_games, dtype=np.int64)

    def capture(act, pos_p, pos_e, step_index):
        """Mark captures among the live evaders of games `act`; returns their distances."""
        dist = pursuer_evader_distance(pos_p, pos_e, alive[act])
        caught = np.min(dist, axis=1) < r_c
        if caught.any():
            g, i = np.nonzero(caught)
            capture_step[act[g], i] = step_index
            alive[act[g], i] = False
            dist[g, :, i] = np.inf
        return dist

    act = np.arange(n_games)
    dist = capture(act, p, e, 0)
    hints = np.full((n_games, n_e, 1), PAD, dtype=np.int64)
    running = alive.any(axis=1)
    frames_p, frames_e = ([p.copy()], [e.copy()]) if record else (None, None)

    for k in range(n_steps):
        if not running[act].all():
            keep = running[act]
            act, dist = act[keep], dist[keep]
            if len(act) == 0:
                break
        pa, ea, alive_a = p[act], e[act], alive[act]
        ctx = StepContext(
            pa, ea, alive_a, arena=arena, dt=dt, v_max=V_MAX, target=goal, distance=dist, hint=hints[act]
        )
        u_p = p_fn(ctx)
        u_e = np.where(alive_a[..., None], e_fn(ctx), 0.0)
        if hasattr(ctx, "cell_labels"):
            width = ctx.cell_labels.shape[2]
            if width > hints.shape[2]:
                hints = np.concatenate(
                    [hints, np.full((n_games, n_e, width - hints.shape[2]), PAD, dtype=np.int64)], axis=2
                )
            hints[act, :, :width] = ctx.cell_labels
            hints[act, :, width:] = PAD
        pa = arena.project(pa + dt * u_p)
        ea = arena.project(ea + dt * u_e)
        p[act], e[act] = pa, ea
        dist = capture(act, pa, ea, k + 1)
        steps[act] = k + 1
        running[act] = alive[act].any(axis=1)
        if record:
            frames_p.append(p.copy())
            frames_e.append(e.copy())

    capture_times = np.where(capture_step >= 0, capture_step * dt, np.nan)
    return GameResults(
        capture_times=capture_times,
        capture_step=capture_step,
        steps=steps,
        dt=dt,
        t_max=t_max,
        capture_radius=r_c,
        arena=arena,
        pursuer_policy=pursuer_policy,
        evader_policy=evader_policy,
        pursuer_paths=np.stack(frames_p) if record else None,
        evader_paths=np.stack(frames_e) if record else None,
    )
