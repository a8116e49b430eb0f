"""DAgger from a planner, the learners' pretraining (a config's `pretrain:` section): the loop
and its resumable iteration files (loop.py), the labelled episodes it learns from
(labels.py) and their Ray task (tasks.py). docs/training.md tells the design."""

from farm.alloc.training.dagger.loop import (
                                                 Pretrained,
                                                 fit_actor,
                                                 iteration_file,
                                                 latest_iteration,
                                                 pretrain,
                                                 saved_iterations,
)

__all__ = ["pretrain", "Pretrained", "fit_actor", "iteration_file", "saved_iterations", "latest_iteration"]
