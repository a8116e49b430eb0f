"""Planners: allocators that look ahead with the env's own model (docs/model.md section 7).

Six planners behind the registry's interface (farm.alloc.allocators), one file each:
`intercept` (greedy nearest that anticipates the advance), `transport` (intercept whose
defenders commit to rows), `mmr` (greedy maximum marginal return), `receding_horizon` (a
program over the next H steps), `minimax` (that program against the intruders' worst
replies) and `subregions` (its Ray actor in band_actor.py: bands of rows planned apart).
Made as `cls(config, client, **options)`, they answer `predict(obs) -> (action, state)` with
an action that the env's `action_map` turns into the move probabilities they want
(action_from_probabilities). They know what the env knows and nothing else: the config, the
intruders' advance and drift and the capture-time client's statistics (farm.alloc.game.model).
The shared core is core.py (levels(), the level programs). Adding a planner is one new file
holding a subclass of core._Planner (its options the keywords of its __init__, its
`probabilities(D, I)` the move probabilities it wants) and one `register_allocator` line in
farm/alloc/allocators/__init__.py."""

from farm.alloc.allocators.planners.core import Levels, action_from_probabilities, advance_matrix, levels
from farm.alloc.allocators.planners.intercept import Intercept
from farm.alloc.allocators.planners.minimax import Minimax
from farm.alloc.allocators.planners.mmr import MaxMarginalReturn
from farm.alloc.allocators.planners.receding_horizon import RecedingHorizon
from farm.alloc.allocators.planners.subregions import SubRegions
from farm.alloc.allocators.planners.transport import Transport

__all__ = ["Intercept", "MaxMarginalReturn", "Minimax", "RecedingHorizon", "SubRegions", "Transport", "Levels",
           "levels", "action_from_probabilities", "advance_matrix"]
