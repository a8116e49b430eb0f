"""Planners: allocators that look ahead with the env's own model (docs/model.md section 7).

Five planners behind the registry's interface (farm.alloc.policies.registry): made as
`cls(config, client, **options)`, they answer `predict(obs) -> (action, state)` with an
action that the env's `action_map` turns into the move probabilities they want
(action_from_probabilities). They know what the env knows and nothing else: the config,
the intruders' advance and drift (farm.alloc.model.advance_intruders) and the
capture-time client's statistics (farm.alloc.model.EngagementModel; all the team-size
pairs a decision needs in one client call, and kept, so a Ray actor is asked once per
pair).

- `intercept` (Intercept): greedy nearest that anticipates the advance. Each cell's
  defenders head for the intruder mass they can meet earliest and wait for it there
  rather than cross it (the swap that leaves greedy_nearest with nothing). No client.
- `transport` (Transport): intercept whose defenders commit to rows: the defenders, in
  whole units, matched in row order to the rows' intruder mass (1-D optimal transport), each
  part heading straight for its row's earliest meeting. Intercept re-splits its mass every
  step and so spreads it by diffusion, which leaves a wide front's outer rows unmet. No client.
- `mmr` (MaxMarginalReturn): greedy maximum marginal return for one step (den Broeder et
  al. 1959): defender mass goes, a chunk at a time, to the coming intruder cell whose
  expected eliminated mass grows most per defender.
- `receding_horizon` (RecedingHorizon): a program over the next H steps (scipy.optimize,
  HiGHS) maximising the env's own expected reward summed over them; the first step is
  applied and the plan made again at the next call.
- `subregions` (SubRegions): the paper's second route to larger maps: the rows cut into
  bands, each planned on its own by another planner with its share of the force, in
  parallel on Ray actors, the plans joined.

A target cell's defender count is priced by levels (levels()): a few ranges of counts,
each one game of the capture-time service. Under `team_sizes: lattice` they are the
counts that round and snap to each lattice size; under `exact` the lattice sizes
themselves. Each range is kept a margin inside the rounding thresholds, so that the
action the softmax map realises (which leaks a share exp(-2 beta) of a cell's mass to
each move it does not want) still plays the planned game.

Every density is a vector over the N x N cells in cell order, c = row * N + col; a
defender count is a density times n_defenders.

One file per planner: intercept.py, transport.py, mmr.py, receding_horizon.py,
subregions.py (its Ray actor in band_actor.py), beside the shared core
(core.py: action_from_probabilities, advance_matrix, Levels and levels(), the option
checks, the base class _Planner with Intercept's rule, and _Rates, the statistics kept).
Adding a planner is one new file holding a subclass of core._Planner (its options the
keywords of its __init__, its `probabilities(D, I)` the move probabilities it wants) and
one `register_policy` line in farm/alloc/policies/__init__.py.
"""

from farm.alloc.policies.planners.core import Levels, action_from_probabilities, advance_matrix, levels
from farm.alloc.policies.planners.intercept import Intercept
from farm.alloc.policies.planners.mmr import MaxMarginalReturn
from farm.alloc.policies.planners.receding_horizon import RecedingHorizon
from farm.alloc.policies.planners.subregions import SubRegions
from farm.alloc.policies.planners.transport import Transport

__all__ = ["Intercept", "MaxMarginalReturn", "RecedingHorizon", "SubRegions", "Transport", "Levels", "levels",
           "action_from_probabilities", "advance_matrix"]
