"""`farm experiments`: trainings over a grid of settings and seeds as Ray Tune trials on one
capture-time service. The config (config.py), the plan (plan.py), one trial (trial.py; its
Tune side, tune.py), the run (run.py), the folder (farm.studies.experiment_folder, below the
claims too), the tables (tables.py), the learning curves (results.py) and the progress display
(display.py). docs/experiments.md tells how it runs and resumes."""

from farm.studies.experiments.config import (
                                             RESERVED_FIELDS,
                                             ExperimentConfig,
                                             field_problem,
                                             load_experiment_config,
)
from farm.studies.experiment_folder import (
                                             MANIFEST,
                                             RESULT,
                                             TUNE_DIR,
                                             ExperimentFolder,
                                             is_experiment,
)
from farm.studies.experiments.plan import Plan, Trial, plan, trial_cpus
from farm.studies.experiments.run import ExperimentError, run_experiment
from farm.studies.experiments.tables import (
                                             TIMING_COLUMNS,
                                             format_summary,
                                             summary_table,
                                             summary_view,
                                             trials_table,
)

__all__ = ["ExperimentConfig", "load_experiment_config", "field_problem", "RESERVED_FIELDS", "Trial", "Plan", "plan",
           "trial_cpus", "run_experiment", "ExperimentError", "ExperimentFolder", "is_experiment", "trials_table",
           "summary_table", "summary_view", "format_summary", "TIMING_COLUMNS", "MANIFEST", "RESULT", "TUNE_DIR"]
