"""Evader: ascend its cell's area gradient (beyond the paper).

u ~ sum_j (L_j / |x_p^j - x_e|) (C_bj - x_e) over neighbouring pursuers j, the
negative of the pursuers' pull of eq. 7; with no pursuer neighbour, move to the
centroid.
"""

import numpy as np

from numpy_engine.policies.centroid import centroid
from numpy_engine.policies.context import StepContext, unit_velocity
from numpy_engine.policies.registry import evader_policy


@evader_policy("area_max")
def area_max(ctx: StepContext) -> np.ndarray:
    nb = ctx.neighbours  # (A, n_e, n_p)
    dist = np.swapaxes(ctx.distance, 1, 2)
    weight = np.where(nb, ctx.shared_length / np.where(nb, dist, 1.0), 0.0)
    pull = ctx.shared_midpoint - ctx.evaders[:, :, None, :]  # (A, n_e, n_p, 2)
    wx = np.cumsum(weight * pull[..., 0], axis=2)[..., -1]
    wy = np.cumsum(weight * pull[..., 1], axis=2)[..., -1]
    heading = ctx.evaders + np.stack([wx, wy], axis=-1)
    u = unit_velocity(heading, ctx.evaders, ctx.v_max)
    return np.where(nb.any(axis=2)[..., None], u, centroid(ctx))
