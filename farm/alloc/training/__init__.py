"""Training an allocator with stable-baselines3 (`farm train`): the config (config.py), the
callbacks (callbacks.py), the exact-resume state (state.py), DAgger from a planner
(dagger/), the run folder it writes (runs.py), its tracking (tracking.py) and the training
itself (train.py). docs/training.md tells the design."""

from farm.alloc.training.callbacks import AfterUpdates, Checkpointer, DivergenceGuard, StepProgress, UpdateTimer
from farm.alloc.training.config import (
                                        ALGOS,
                                        POLICY_KWARGS,
                                        EvalParams,
                                        PPOParams,
                                        PretrainParams,
                                        SACParams,
                                        ServiceParams,
                                        TD3Params,
                                        TrainConfig,
                                        load_train_config,
                                        store_of,
)
from farm.alloc.training.state import RunState
from farm.alloc.training.train import EVAL_SEED_OFFSET, train

__all__ = ["ALGOS", "PPOParams", "SACParams", "PretrainParams", "TrainConfig", "TD3Params", "EvalParams",
           "ServiceParams", "load_train_config", "store_of", "train",
           "UpdateTimer", "DivergenceGuard", "StepProgress", "AfterUpdates", "Checkpointer", "RunState",
           "EVAL_SEED_OFFSET", "POLICY_KWARGS"]
