"""Planners: allocators that look ahead with the env's own model (docs/model.md section 7).

Five planners behind the registry's interface (farm.alloc.policies.registry), one file each:
`intercept` (intercept.py: greedy nearest that anticipates the advance), `transport`
(transport.py: intercept whose defenders commit to rows), `mmr` (mmr.py: greedy maximum
marginal return), `receding_horizon` (receding_horizon.py: a program over the next H steps)
and `subregions` (subregions.py, its Ray actor in band_actor.py: bands of rows planned apart).
Made as `cls(config, client, **options)`, they answer `predict(obs) -> (action, state)` with
an action that the env's `action_map` turns into the move probabilities they want
(action_from_probabilities). They know what the env knows and nothing else: the config, the
intruders' advance and drift and the capture-time client's statistics (farm.alloc.model).
The shared core is core.py (levels(): a target cell's count priced by a few game levels).
Adding a planner is one new file holding a subclass of core._Planner (its options the
keywords of its __init__, its `probabilities(D, I)` the move probabilities it wants) and one
`register_policy` line in farm/alloc/policies/__init__.py.
"""

from farm.alloc.policies.planners.core import Levels, action_from_probabilities, advance_matrix, levels
from farm.alloc.policies.planners.intercept import Intercept
from farm.alloc.policies.planners.mmr import MaxMarginalReturn
from farm.alloc.policies.planners.receding_horizon import RecedingHorizon
from farm.alloc.policies.planners.subregions import SubRegions
from farm.alloc.policies.planners.transport import Transport

__all__ = ["Intercept", "MaxMarginalReturn", "RecedingHorizon", "SubRegions", "Transport", "Levels", "levels",
           "action_from_probabilities", "advance_matrix"]
