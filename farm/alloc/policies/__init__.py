"""Allocators behind one interface, listed once (registry.py): the baselines (baselines.py),
the planners (planners/, one file each) and the learned ones (learned.py).

Adding an allocator is one file holding its maker and one `register_policy` line below (or
in your own module: registering there puts it in every evaluation of that process).
"""

from farm.alloc.policies import learned
from farm.alloc.policies.baselines import (
                                          GreedyNearestIntruder,
                                          SpreadEvenly,
                                          StayAtBase,
)
from farm.alloc.policies.mixture import Mixture
from farm.alloc.policies.planners import (
                                          Intercept,
                                          MaxMarginalReturn,
                                          Minimax,
                                          RecedingHorizon,
                                          SubRegions,
                                          Transport,
)
from farm.alloc.policies.registry import (
                                          KINDS,
                                          PolicyEntry,
                                          PolicySpec,
                                          make_policy,
                                          policy_entry,
                                          policy_names,
                                          register_policy,
                                          unregister_policy,
)

__all__ = ["PolicyEntry", "PolicySpec", "KINDS", "register_policy", "unregister_policy", "policy_entry",
           "policy_names", "make_policy"]

register_policy("stay_at_base", StayAtBase.make, kind="baseline")
register_policy("greedy_nearest", GreedyNearestIntruder.make, kind="baseline")
register_policy("spread_evenly", SpreadEvenly.make, kind="baseline")
register_policy("intercept", Intercept, kind="planner")
register_policy("mmr", MaxMarginalReturn, kind="planner")
register_policy("receding_horizon", RecedingHorizon, kind="planner")
register_policy("transport", Transport, kind="planner")
register_policy("minimax", Minimax, kind="planner", reference=False)
register_policy("subregions", SubRegions, kind="planner", reference=False)
register_policy("td3", learned.td3, kind="learned")
register_policy("ppo", learned.ppo, kind="learned")
register_policy("sac", learned.sac, kind="learned")
register_policy("mixture", Mixture, kind="mixture", reference=False)
