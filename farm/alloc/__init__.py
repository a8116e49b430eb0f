"""High-level allocation: the grid MDP as a gymnasium env (`farm/SwarmAllocation-v0`).

Importing this package registers the env:
    import gymnasium, farm.alloc
    env = gymnasium.make("farm/SwarmAllocation-v0", grid_size=3, n_defenders=100, n_intruders=50)
"""

import gymnasium

from farm.alloc.config import AllocConfig
from farm.alloc.env import SwarmAllocationEnv, moves, n_actions

ENV_ID = "farm/SwarmAllocation-v0"
if ENV_ID not in gymnasium.registry:
    gymnasium.register(ENV_ID, entry_point="farm.alloc.env:SwarmAllocationEnv")

__all__ = ["AllocConfig", "SwarmAllocationEnv", "ENV_ID", "moves", "n_actions"]
