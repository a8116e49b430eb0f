"""The path Ray Tune's saved state of an experiment written by swarm-farm 0.5 names
(farm.experiments_tune.Progress, its progress callback), kept so that such a folder still
resumes; imports Ray, as farm.studies.experiments.tune does."""

from farm.studies.experiments.tune import Progress

__all__ = ["Progress"]
