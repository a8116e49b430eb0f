"""Policy registry: every policy is a small function of a StepContext, one file each.

A policy returns velocities, pursuers (A, n_p, 2) or evaders (A, n_e, 2) float64,
with speeds at most ctx.v_max. Importing this package registers the built-ins.
"""

from numpy_engine.policies import (  # noqa: F401  (registration side effect)
    area_max,
    area_min,
    centroid,
    constant_area,
    pure_pursuit,
    target,
)
from numpy_engine.policies.context import StepContext, unit_velocity
from numpy_engine.policies.registry import (
    EVADER_POLICIES,
    PURSUER_POLICIES,
    evader_policy,
    get_evader_policy,
    get_pursuer_policy,
    pursuer_policy,
)

__all__ = [
    "StepContext",
    "unit_velocity",
    "PURSUER_POLICIES",
    "EVADER_POLICIES",
    "pursuer_policy",
    "evader_policy",
    "get_pursuer_policy",
    "get_evader_policy",
]
