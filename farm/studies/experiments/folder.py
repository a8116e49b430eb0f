"""An experiment's folder: farm.studies.experiment_folder, the one reader and writer of its files,
named here too as the experiments' own."""

from farm.studies.experiment_folder import (
    MANIFEST,
    RESULT,
    TUNE_DIR,
    ExperimentFolder,
    finished_trials,
    is_experiment,
    read_manifest,
)

__all__ = ["ExperimentFolder", "is_experiment", "read_manifest", "finished_trials", "MANIFEST", "RESULT", "TUNE_DIR"]
