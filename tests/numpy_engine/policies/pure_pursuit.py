"""Pursuer: head at full speed for the nearest live evader (paper eqs. 9-10)."""

import numpy as np

from numpy_engine.policies.context import StepContext, unit_velocity
from numpy_engine.policies.registry import pursuer_policy


@pursuer_policy("pure_pursuit")
def pure_pursuit(ctx: StepContext) -> np.ndarray:
    nearest = np.argmin(ctx.distance, axis=2)  # (A, n_p)
    goal = np.take_along_axis(ctx.evaders, nearest[..., None], axis=1)
    return unit_velocity(goal, ctx.pursuers, ctx.v_max)
