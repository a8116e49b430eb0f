"""Pursuer: area minimization (paper Alg. 1, eqs. 7-8).

A pursuer that neighbours live evaders heads for the midpoint C_b of the edge it
shares with the nearest of them; any other pursuer uses pure pursuit.
"""

import numpy as np

from numpy_engine.policies.context import StepContext, unit_velocity
from numpy_engine.policies.pure_pursuit import pure_pursuit
from numpy_engine.policies.registry import pursuer_policy


@pursuer_policy("area_min")
def area_min(ctx: StepContext) -> np.ndarray:
    dist = np.where(ctx.neighbours, np.swapaxes(ctx.distance, 1, 2), np.inf)  # (A, n_e, n_p)
    chosen = np.argmin(dist, axis=1)  # (A, n_p) nearest neighbouring evader
    has_neighbour = np.isfinite(np.min(dist, axis=1))
    mid = np.take_along_axis(ctx.shared_midpoint, chosen[:, None, :, None], axis=1)[:, 0]
    u = unit_velocity(mid, ctx.pursuers, ctx.v_max)
    if has_neighbour.all():
        return u
    return np.where(has_neighbour[..., None], u, pure_pursuit(ctx))
