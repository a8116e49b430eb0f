"""The batched pursuit-evasion engine: B games of the same team sizes and policies
stepped together; finished games drop out by mask.

Semantics (docs/model.md section 1): explicit Euler with fixed dt; at step k the
controls of every agent come from the state at k, then all agents move, then
positions are projected onto the arena; evader i is captured at t = (k+1) dt
when its distance to the nearest pursuer is below r_c (strictly), or at t = 0 if
it starts that close; captured evaders leave the game at once.
"""

from __future__ import annotations

import numpy as np

from numpy_engine.geometry import PAD
from numpy_engine.policies import StepContext, get_evader_policy, get_pursuer_policy
from numpy_engine.policies.context import pursuer_evader_distance
from workers.arena import make_arena
from workers.engine import GameResults, checked_games

__all__ = ["ENGINE_VERSION", "simulate_games", "V_MAX"]  # its results are workers.GameResults

ENGINE_VERSION = "1.1.0"
V_MAX = 1.0
MAX_STEPS = 10_000_000


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


def simulate_games(pursuers, evaders, *, pursuer_policy: str = "area_min", evader_policy: str = "centroid",
                   capture_radius: float = 0.25, dt: float = 0.01, t_max: float = 60.0, target=(0.0, 5.0),
                   arena=None, record: bool = False) -> GameResults:
    """Play B independent games to the end.

    pursuers: (B, n_p, 2) float64, evaders: (B, n_e, 2) float64 initial
    positions inside the arena; arena: None for the square [0, 10]^2, else the
    vertices (k, 2) of a convex polygon. Returns GameResults.
    """
    p_fn = get_pursuer_policy(pursuer_policy)
    e_fn = get_evader_policy(evader_policy)
    arena, p, e, r_c, dt, t_max, goal, n_steps = checked_games(pursuers, evaders, arena, capture_radius, dt, t_max,
                                                               target)

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
        if ctx.cell_labels is not None:
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
    return GameResults(capture_times, capture_step, steps, dt, t_max, r_c, arena, pursuer_policy, evader_policy,
                       escape_times=np.full(capture_times.shape, np.nan), escape_step=np.full(capture_step.shape, -1),
                       pursuer_paths=np.stack(frames_p) if record else None,
                       evader_paths=np.stack(frames_e) if record else None, engine_version=ENGINE_VERSION)
