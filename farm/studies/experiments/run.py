"""`farm experiments CONFIG --out DIR`: many trainings as one Ray Tune experiment, over a grid
of settings and seeds, every trial evaluated against the registered baselines and planners on
the same seeded episodes, all trials on ONE capture-time service. docs/experiments.md tells
how it runs, shares the CPUs with the service's games, and resumes."""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path

import pandas as pd

from farm.alloc.evaluation.evaluate import reference_specs
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.lattice import lattice_groups, warm_lattices
from farm.alloc.training import TrainConfig
from farm.core.errors import SwarmFarmError
from farm.core.output import check_writable_folder
from farm.studies.claims import claims_over_seeds, write_claims_over_seeds
from farm.studies.experiments.config import ExperimentConfig
from farm.studies.experiments.display import PROGRESS, Display
from farm.studies.experiment_folder import TUNE_DIR, ExperimentFolder
from farm.studies.experiments.plan import Plan, plan, trial_cpus
from farm.studies.experiments.storage import ExperimentStorage, is_uri
from farm.studies.experiments.tables import manifest_trials, summary_table, trials_table
from farm.studies.experiments.trial import run_trial, trial_dirname

__all__ = ["run_experiment", "ExperimentError", "MAX_FAILURES"]

MAX_FAILURES = 2


class ExperimentError(SwarmFarmError):
    """A trial that failed (its error's first line, naming the trial)."""


def run_experiment(config: ExperimentConfig, out, *, source: str = "experiments", address: str | None = None,
                   workers: int | None = None, show_progress: bool = True,
                   warm: bool = True, opponent_procs: int = 1) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Run or resume an experiment into out (docs/experiments.md): a local folder, or a URI of
    object storage (s3://bucket/path, any filesystem pyarrow names: farm.studies.experiments.storage);
    returns (trials.csv's table, summary.csv's table, info).

    address: a Ray cluster to join (default $RAY_ADDRESS, else a local Ray of max(2,
    workers) CPUs); workers: trials at once (default: the cluster's CPUs); warm: False
    skips the lattice warm-up, in the driver and in every trial (the tests use it to make
    trials miss on a cold store); opponent_procs: the processes answering the frozen allocator's
    moves in an intruders' trial (farm.alloc.training.train's; a speed setting, not the trials':
    a resumed experiment keeps the one it started with). info: trials run this time and before, the CPUs per
    trial, the warm-up's cases and seconds, the wall seconds, the claims' files and the
    learning curves' figure written (claims: a list of paths, learning_curves: a path or None;
    written: every file the driver wrote; URIs for an experiment in object storage).
    ConfigError (one line) for bad input before Ray starts; ExperimentError naming the first
    trial that failed (after the tables of the others are written).
    """
    from farm.alloc.envs.move_helpers import check_procs

    check_procs(opponent_procs)
    the_plan, storage, tracker, before = _prepare(config, out, source, workers, warm)
    info: dict = {"trials": len(the_plan.trials), "finished_before": len(before), "warmed_cases": 0}
    t0 = time.perf_counter()
    results = _run_trials(the_plan, storage, tracker, before, info, address=address, workers=workers, warm=warm,
                          show_progress=show_progress, opponent_procs=opponent_procs)
    info["seconds"] = time.perf_counter() - t0
    trials, summary = _write_results(the_plan, storage, info)
    info["tune_finished"] = sum(1 for r in results if r.error is None and (r.metrics or {}).get("phase") == "done")
    _raise_failures(results, len(trials), len(the_plan.trials))
    return trials, summary, info


def _prepare(config: ExperimentConfig, out, source: str, workers: int | None, warm: bool):
    """(plan, storage, MLflow callback or None, keys of the trials finished before): the
    experiment planned, its storage checked to hold this experiment or none (its digest) and its
    manifest written; all before Ray starts, so that bad input (workers, a folder that cannot be
    written, object storage that cannot work, a tracking URI that cannot) is one line. Without
    warm, no trial warms the lattice."""
    from farm.runtime import check_workers

    check_workers(workers)
    if not is_uri(out):
        check_writable_folder(out, "out")  # before Ray, the lattice and the trials
    the_plan = plan(config, source)
    storage = ExperimentStorage(out)
    storage.check()  # a URI's storage: supported, picklable, answering, its bucket there
    tracker = _mlflow_callback(config, the_plan, storage)
    if not warm:
        for t in the_plan.trials:
            t.config["service"]["warm_lattice"] = False
    storage.check_for(the_plan.digest)
    storage.write_manifest({"name": the_plan.name, "digest": the_plan.digest,
                            "config": config.model_dump(mode="json", exclude_unset=True), "store": the_plan.store,
                            "fields": the_plan.fields, "trials": manifest_trials(the_plan)})
    before = [t.key for t in the_plan.trials if storage.finished(t.key)]
    return the_plan, storage, tracker, before


def _run_trials(the_plan: Plan, storage: ExperimentStorage, tracker, before: list, info: dict, *,
                address: str | None, workers: int | None, warm: bool, show_progress: bool, opponent_procs: int = 1):
    """The Tune experiment's ResultGrid, run (or resumed) on one capture-time service actor over
    the plan's store: the lattice of every trial's maps warmed first while a trial is left to run
    (unless warm is False), then the trials, `workers` at a time (default: the cluster's CPUs),
    the CPUs shared between them (trial_cpus). Adds warmed_cases, warm_seconds, workers,
    trial_cpus, cluster_cpus and started to info."""
    from farm.runtime import starts_local_ray
    from farm.service.client import open_client

    starts_ray = starts_local_ray(address)
    first = the_plan.trials[0].config["env"]
    t0 = time.perf_counter()
    with open_client(AllocConfig(**first).game_settings(), mode="ray", store=the_plan.store, address=address,
                     num_cpus=max(2, workers or 2) if starts_ray else None) as client:
        import ray

        if warm and len(before) < len(the_plan.trials):  # a trial left to run
            envs = [env for t in the_plan.trials if t.config["service"]["warm_lattice"]
                    for env in TrainConfig(**t.config).envs()]
            info["warmed_cases"] = warm_lattices(client, lattice_groups(envs), show_progress)
        info["warm_seconds"] = time.perf_counter() - t0
        cpus = float(ray.cluster_resources().get("CPU", 0))
        k = min(workers or max(1, int(cpus)), len(the_plan.trials))
        share = trial_cpus(cpus, k)
        info.update(workers=k, trial_cpus=share, cluster_cpus=cpus)
        display = Display(the_plan, show_progress, before)
        PROGRESS["display"] = display
        try:
            results = _fit(the_plan, storage, k, share, [] if tracker is None else [tracker], opponent_procs)
        finally:
            PROGRESS.pop("display", None)
            display.close()
        info["started"] = len(display.started_keys)
    return results


def _write_results(the_plan: Plan, storage: ExperimentStorage, info: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(trials, summary): the finished trials' tables, the claims over the seeds and the learning
    curves, written into a stage and published to the storage together. Adds claims,
    learning_curves and written (where they are in the storage) to info."""
    with storage.staged() as stage:
        storage.stage_results(stage, [t.key for t in the_plan.trials])
        trials = trials_table(the_plan, stage)
        summary = summary_table(the_plan.fields, trials)
        written = ExperimentFolder(stage).write_tables(trials, summary)
        found = _write_claims_and_curves(stage)
        files = [p.name for p in [*written, *found["claims"], found["learning_curves"]] if p is not None]
        storage.publish(stage, files)
    info["claims"] = [storage.where(p.name) for p in found["claims"]]
    info["learning_curves"] = None if found["learning_curves"] is None else storage.where(found["learning_curves"].name)
    info["written"] = [storage.where(name) for name in files]
    return trials, summary


def _raise_failures(results, finished: int, planned: int) -> None:
    """ExperimentError naming the first trial that failed, or, when fewer than planned trials
    finished (Tune was stopped, Ctrl+C; its state is saved), how many are left."""
    errors = [(r.error, r.path) for r in results if r.error is not None]
    if errors:
        error, path = errors[0]
        problem = (str(error).strip().splitlines() or [type(error).__name__])[-1]
        raise ExperimentError(f"trial {Path(path).name} failed ({len(errors)} of {len(results)} failed): {problem}")
    if finished < planned:
        raise ExperimentError(f"{planned - finished} of {planned} trials unfinished "
                              f"(interrupted); run the same command again to go on")


def _write_claims_and_curves(out: Path) -> dict:
    """The paper's claims over the seeds (claims.csv, claims_seeds.csv; when the experiment has
    a C_capture 0 and 1.5 pair: farm.studies.claims.claims_over_seeds) and the learning curves
    over seeds (learning_curves.png); returns {claims: the files written, learning_curves: the
    figure's path or None}."""
    from farm.studies.experiments.results import write_learning_curves

    found = claims_over_seeds(out)
    return {"claims": write_claims_over_seeds(out, found) if found.pair is not None and found.rows else [],
            "learning_curves": write_learning_curves(out)}


def _mlflow_callback(config: ExperimentConfig, the_plan: Plan, storage: ExperimentStorage):
    """The MLflow logger (farm.studies.experiments.tracking.TrialRuns) for config.tracking.mlflow
    (None when it is not set): every trial an MLflow run of the experiment named there (default:
    the experiment's name), made here first (farm.core.tracking.open_experiment: the URI checked,
    the plan's capture-time store refused as a tracking store; an SQLite store keeps its artifacts
    beside its database). ConfigError (one line) when the URI cannot work."""
    params = config.tracking.mlflow
    if params is None:
        return None
    from farm.core.tracking import open_experiment
    from farm.studies.experiments.tracking import TrialRuns

    name = the_plan.name
    experiment = params.experiment or name
    open_experiment(params, experiment, store=the_plan.store)
    return TrialRuns(params, experiment, storage.uri.split("?")[0],
                     tags={"farm.kind": "experiment", "farm.experiment": name})


def _fit(plan: Plan, storage: ExperimentStorage, workers: int, share: float, callbacks: list,
         opponent_procs: int = 1):
    """Run (or restore and go on with) the Tune experiment in the storage; returns its
    ResultGrid. callbacks: Tune callbacks beside the progress display (the MLflow logger); a
    restored experiment keeps the callbacks it was started with (Tune saves them in its state; an
    older folder's by old module paths, farm.studies.experiments.legacy)."""
    from ray import tune

    from farm.studies.experiments.legacy import old_names

    trainable = tune.with_resources(run_trial, {"cpu": share})
    root, filesystem = storage.tune_storage()
    path = f"{root}/{TUNE_DIR}"
    with old_names(), _quiet_tune():
        return _tuner(tune, trainable, plan, storage, path, root, filesystem, workers, callbacks,
                      opponent_procs).fit()


def _tuner(tune, trainable, plan: Plan, storage: ExperimentStorage, path: str, root: str, filesystem, workers: int,
           callbacks: list, opponent_procs: int = 1):
    """The Tune experiment at path restored to go on, or a new one of the plan's trials."""
    from farm.studies.experiments.tune import Progress

    if tune.Tuner.can_restore(path, storage_filesystem=filesystem):
        tuner = tune.Tuner.restore(path, trainable=trainable, resume_unfinished=True, resume_errored=True,
                                   storage_filesystem=filesystem)
    else:
        policies = reference_specs()  # the registry's, as this process has it: carried to every trial
        specs = [{"trial": t.model_dump(), "storage": storage.uri, "episodes": plan.episodes,
                  "eval_seed": plan.eval_seed, "policies": policies} for t in plan.trials]
        if opponent_procs > 1:
            specs = [{**spec, "opponent_procs": opponent_procs} for spec in specs]
        tuner = tune.Tuner(
            trainable,
            param_space={"spec": tune.grid_search(specs)},
            tune_config=tune.TuneConfig(max_concurrent_trials=workers, reuse_actors=True,
                                        trial_dirname_creator=trial_dirname, trial_name_creator=trial_dirname),
            run_config=tune.RunConfig(name=TUNE_DIR, storage_path=root, storage_filesystem=filesystem,
                                      failure_config=tune.FailureConfig(max_failures=MAX_FAILURES),
                                      checkpoint_config=tune.CheckpointConfig(num_to_keep=2),
                                      verbose=0, callbacks=[Progress(), *callbacks]),
        )
    return tuner


# Ray Tune's own output, off while an experiment runs (its progress is farm's bar): the new
# output engine prints a configuration box whatever the verbosity, the legacy one is silent at
# verbose=0; the warning that saving the experiment's state took long is meant for remote storage;
# the warning that TensorboardX is missing is about Tune's own result logger (each trial's
# TensorBoard logs are SB3's, in its run folder).
_TUNE_QUIET = {"RAY_AIR_NEW_OUTPUT": "0", "TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S": "0"}
_TUNE_QUIET_LOGGER = "ray.tune.utils.callback"


@contextmanager
def _quiet_tune():
    """Set _TUNE_QUIET's variables that are not set, and _TUNE_QUIET_LOGGER's level to errors
    only, for the block."""
    import logging

    added = [name for name in _TUNE_QUIET if name not in os.environ]
    os.environ.update({name: _TUNE_QUIET[name] for name in added})
    quiet = logging.getLogger(_TUNE_QUIET_LOGGER)
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        yield
    finally:
        quiet.setLevel(level)
        for name in added:
            os.environ.pop(name, None)


