"""The `intercept` planner (Intercept): greedy nearest that anticipates the intruders' advance."""

from __future__ import annotations

from farm.alloc.allocators.planners.core import _Planner
from farm.alloc.game.config import AllocConfig

__all__ = ["Intercept"]


class Intercept(_Planner):
    """Greedy nearest that anticipates the intruders' advance, and waits rather than swap.

    Each cell's defenders go one step (one king move, a step per coordinate) towards the
    cell where they can meet intruder mass earliest (_Planner.meetings: the smallest k
    such that the intruders' cell k steps on, in their expected row under drift, is
    within k moves). Meeting the intruders at their next cell means staying put when they
    are one column to the right: the defenders wait to be met instead of crossing them,
    the swap that leaves greedy_nearest with nothing. Cells that can meet nobody stay.
    It asks no statistics.

    config: AllocConfig; client: accepted and unused; ties: "split" (default) shares a
    cell's mass among the intruder cells it meets earliest in proportion to their mass,
    "largest" sends it all to the largest. "split" is the default because it is measured
    better (docs/model.md section 7): the capture curves are concave, and all the
    defenders on one row leave the other rows unmet. A bad ties or an unknown option is a
    ConfigError naming it.
    """

    name = "intercept"

    def __init__(self, config: AllocConfig, client=None, *, ties: str = "split", **unknown):
        super().__init__(config, client, unknown, ties)

    def probabilities(self, D, I):
        """Intercept's move probabilities (see the class); D is not needed."""
        return self.intercept_probabilities(I)
