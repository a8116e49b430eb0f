"""The path Ray Tune's saved state of an experiment written by swarm-farm 0.5 names
(farm.experiments._trial_dirname, its trials' folder names), kept so that such a folder still
resumes. The experiments themselves are farm.studies.experiments."""

from farm.studies.experiments.trial import trial_dirname as _trial_dirname

__all__ = ["_trial_dirname"]
