"""Evader: head for a fixed target point (default (0, 5), the defenders' side).

The last step lands exactly on the target (speed min(v_max, distance/dt)) and
the evader stays there: unit steps would otherwise oscillate around it.
"""

import numpy as np

from numpy_engine.policies.context import StepContext
from numpy_engine.policies.registry import evader_policy

ARRIVED = 1e-9


@evader_policy("target")
def target(ctx: StepContext) -> np.ndarray:
    h = ctx.target - ctx.evaders
    dist = np.hypot(h[..., 0], h[..., 1])
    speed = np.minimum(ctx.v_max, dist / ctx.dt)
    scale = np.where(dist > ARRIVED, speed / np.where(dist > ARRIVED, dist, 1.0), 0.0)
    return h * scale[..., None]
