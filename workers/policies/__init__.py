"""Policy registry: every policy is a small compiled function of (agent, Step), one file each.

A policy returns its agent's velocity (ux, uy), of speed at most its team's
(Step.vp for pursuers, Step.ve for evaders). workers.policies.registry lists them,
numbers them and makes the compiled dispatch; its docstring says how to add one.
"""

from workers.policies.context import Step, unit_velocity
from workers.policies.registry import (
    EVADER_POLICIES,
    PURSUER_POLICIES,
    Policy,
    evader_velocity,
    get_evader_policy,
    get_pursuer_policy,
    pursuer_velocity,
    register_policy,
    unregister_policy,
)

__all__ = [
    "Step",
    "Policy",
    "unit_velocity",
    "PURSUER_POLICIES",
    "EVADER_POLICIES",
    "get_pursuer_policy",
    "get_evader_policy",
    "register_policy",
    "unregister_policy",
    "pursuer_velocity",
    "evader_velocity",
]
