"""The defenders' policies, the allocators, behind one interface: the baselines (baselines.py),
the planners (planners/, one file each), the learned ones (learned.py) and mixtures of them
(mixture.py), registered in farm.alloc.game.registry.ALLOCATORS.

Adding an allocator is one file holding its maker and one `register_allocator` line below (or
in your own module: registering there puts it in every evaluation of that process).
"""

from farm.alloc.allocators import learned
from farm.alloc.allocators.baselines import GreedyNearestIntruder, SpreadEvenly, StayAtBase
from farm.alloc.allocators.mixture import Mixture
from farm.alloc.allocators.planners import Intercept, MaxMarginalReturn, Minimax, RecedingHorizon, SubRegions, Transport
from farm.alloc.game.registry import ALLOCATORS, Entry, Spec

__all__ = ["ALLOCATORS", "Entry", "Spec", "register_allocator", "unregister_allocator", "allocator_entry",
           "allocator_names", "make_allocator"]

register_allocator = ALLOCATORS.register
unregister_allocator = ALLOCATORS.unregister
allocator_entry = ALLOCATORS.entry
allocator_names = ALLOCATORS.names
make_allocator = ALLOCATORS.make

register_allocator("stay_at_base", StayAtBase.make, kind="baseline")
register_allocator("greedy_nearest", GreedyNearestIntruder.make, kind="baseline")
register_allocator("spread_evenly", SpreadEvenly.make, kind="baseline")
register_allocator("intercept", Intercept, kind="planner")
register_allocator("mmr", MaxMarginalReturn, kind="planner")
register_allocator("receding_horizon", RecedingHorizon, kind="planner")
register_allocator("transport", Transport, kind="planner")
register_allocator("minimax", Minimax, kind="planner", reference=False)
register_allocator("subregions", SubRegions, kind="planner", reference=False)
register_allocator("td3", learned.td3, kind="learned")
register_allocator("ppo", learned.ppo, kind="learned")
register_allocator("sac", learned.sac, kind="learned")
register_allocator("mixture", Mixture, kind="mixture", reference=False)
