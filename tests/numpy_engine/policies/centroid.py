"""Evader: move to the centroid of its own Voronoi cell (paper eq. 12)."""

import numpy as np

from numpy_engine.policies.context import StepContext, unit_velocity
from numpy_engine.policies.registry import evader_policy


@evader_policy("centroid")
def centroid(ctx: StepContext) -> np.ndarray:
    return unit_velocity(ctx.cell_centroid, ctx.evaders, ctx.v_max)
