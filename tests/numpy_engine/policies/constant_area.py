"""Evader: keep the cell's area constant (paper eq. 11).

Head for C_b of the edge shared with the nearest neighbouring pursuer; with no
pursuer neighbour, move to the centroid.
"""

import numpy as np

from numpy_engine.policies.centroid import centroid
from numpy_engine.policies.context import StepContext, unit_velocity
from numpy_engine.policies.registry import evader_policy


@evader_policy("constant_area")
def constant_area(ctx: StepContext) -> np.ndarray:
    dist = np.where(ctx.neighbours, np.swapaxes(ctx.distance, 1, 2), np.inf)  # (A, n_e, n_p)
    chosen = np.argmin(dist, axis=2)  # (A, n_e)
    has_neighbour = np.isfinite(np.min(dist, axis=2))
    mid = np.take_along_axis(ctx.shared_midpoint, chosen[:, :, None, None], axis=2)[:, :, 0]
    u = unit_velocity(mid, ctx.evaders, ctx.v_max)
    return np.where(has_neighbour[..., None], u, centroid(ctx))
