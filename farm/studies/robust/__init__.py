"""`farm robust`: allocators that hold against an adapting enemy, by policy-space response oracles
on the farm (loop.py), over the meta-game's payoffs (payoffs.py) of two populations (members.py);
the config (config.py)."""

from farm.studies.robust.config import RobustConfig, load_robust_config
from farm.studies.robust.loop import Iteration, run_robust

__all__ = ["RobustConfig", "load_robust_config", "Iteration", "run_robust"]
