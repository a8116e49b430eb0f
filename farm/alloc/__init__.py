"""High-level allocation: the two-player grid game of the defenders and the intruders.

Rooms, lowest first: game/ (model, scenarios, the two sides' registries), networks/,
allocators/ and intruders/ (the two sides, neither importing the other), envs/, training/,
evaluation/.

Importing this package registers both sides' policies, the env (`farm/SwarmAllocation-v0`), and
each benchmark scenario (farm.alloc.game.scenarios.SCENARIOS) as `farm/<name>-v0`:
    import gymnasium, farm.alloc
    env = gymnasium.make("farm/SwarmAllocation-v0", grid_size=3, n_defenders=100, n_intruders=50)
    env = gymnasium.make("farm/paper_3x3_c1_0-v0")
and each id's batched form (farm.alloc.envs.vector.SwarmAllocationVectorEnv, B episodes in numpy):
    envs = gymnasium.make_vec("farm/paper_3x3_c1_0-v0", num_envs=16, vectorization_mode="vector_entry_point")
The intruders' side against a frozen allocator (farm.alloc.envs.intruders), as each scenario's
`farm/<name>-intruders-v0`: gymnasium.make("farm/paper_3x3_c1_0-intruders-v0", opponent="stay_at_base")
"""

import gymnasium

import farm.alloc.allocators  # noqa: F401  (registers the allocators)
import farm.alloc.intruders  # noqa: F401  (registers the intruder policies)
from farm.alloc.envs.defenders import SwarmAllocationEnv
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import moves, n_actions
from farm.alloc.game.scenarios import (
    ENTRY_POINT,
    INTRUDER_ENTRY_POINT,
    INTRUDER_VECTOR_ENTRY_POINT,
    SCENARIOS,
    VECTOR_ENTRY_POINT,
    register_scenarios,
)

ENV_ID = "farm/SwarmAllocation-v0"
INTRUDER_ENV_ID = "farm/SwarmIntruders-v0"
if ENV_ID not in gymnasium.registry:
    gymnasium.register(ENV_ID, entry_point=ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT)
if INTRUDER_ENV_ID not in gymnasium.registry:
    gymnasium.register(INTRUDER_ENV_ID, entry_point=INTRUDER_ENTRY_POINT,
                       vector_entry_point=INTRUDER_VECTOR_ENTRY_POINT)
register_scenarios()

__all__ = ["AllocConfig", "SwarmAllocationEnv", "ENV_ID", "INTRUDER_ENV_ID", "moves", "n_actions", "SCENARIOS"]
