"""One experiment trial, Ray Tune's function trainable (run_trial): train the trial (or resume
it), evaluate its trained allocator beside the registered baselines and planners (the one
evaluation of farm.alloc.evaluation.evaluate; a trained intruders' run: its opponent against it and
against the drift law), write its result.json and report it. docs/experiments.md
tells how trials resume and why a finished one never trains again."""

from __future__ import annotations

import time
from pathlib import Path

from farm.alloc.evaluation.evaluate import allocators, evaluate_trained, reference_specs
from farm.alloc.training.runs import RunFolder
from farm.studies.experiments.plan import Trial
from farm.studies.experiments.tables import LEARNED, METRICS_COLUMNS

__all__ = ["run_trial", "trial_dirname"]


def _evaluate(config, run: RunFolder, episodes: int, seed: int, specs):
    """The final model and specs (the baselines and planners) on episodes seed .. seed+episodes-1
    (one client on the shared service); writes farm eval's tables into the run folder (farm
    claims reads them); returns the table."""
    from farm.service.client import open_client

    with open_client(config.env.game_settings(), mode="ray", store=config.service.store) as client:
        policies = allocators(run, config, client, specs)
        return evaluate_trained(run, config, policies, client, episodes, seed, figures=False)[0]


def _evaluate_intruders(config, run: RunFolder, episodes: int, seed: int):
    """A trained intruders' run: its opponent allocator against it (`learned`) and against the
    drift law (`drift`) on episodes seed .. seed+episodes-1; returns the table (policy,
    return_mean, eliminated_mean): the opponent's measures."""
    import pandas as pd

    from farm.alloc.allocators import make_allocator
    from farm.alloc.evaluation.rollout import play
    from farm.alloc.game.config import AllocConfig
    from farm.service.client import open_client

    learned = AllocConfig(**{**config.env.model_dump(), "intruders": "learned",
                             "intruder_options": {"run": str(run.path)}})
    rows = []
    with open_client(config.env.game_settings(), mode="ray", store=config.service.store) as client:
        for name, env in ((LEARNED, learned), ("drift", config.env)):
            opponent = make_allocator(config.opponent.name, env, client, **config.opponent.options)
            played = play(env, opponent, client, episodes, seed)
            rows.append({"policy": name, "return_mean": sum(e.summary["return"] for e in played) / episodes,
                         "eliminated_mean": sum(e.summary["eliminated"] for e in played) / episodes})
    return pd.DataFrame(rows)


def run_trial(params: dict) -> None:
    """The Tune trainable. params: {"spec": {"trial": Trial as plain values, "storage": the
    experiment's folder or URI (ExperimentStorage; an older spec's "dir" instead: the trial's folder in a
    local experiment), "episodes", "eval_seed", "policies": the PolicySpecs to compare with
    (default: the registry's baselines and planners), "opponent_procs": train's (default 1)}}.
    The trial trains in its run folder
    (ExperimentStorage.run_dir), written again from its Tune checkpoint first when it lacks
    it (restore_run)."""
    from ray import tune

    from farm.alloc.training import TrainConfig, train
    from farm.studies.experiments.storage import ExperimentStorage, drop_stale_run, restore_run
    from farm.studies.experiments.tune import PretrainReport, TuneReport

    spec = params["spec"]
    trial = Trial(**spec["trial"])
    storage = ExperimentStorage(spec["storage"] if "storage" in spec else Path(spec["dir"]).parent.parent)
    if storage.finished(trial.key):  # finished before (e.g. the driver died after it): never trained again
        tune.report({**storage.read_result(trial.key), "phase": "done"})
        return
    config = TrainConfig(**trial.config)
    run = RunFolder(storage.run_dir(trial.key))
    drop_stale_run(storage, run, config)
    restore_run(tune.get_checkpoint(), run.path, replay_buffer=config.replay_buffer)
    every = max(1, min(config.checkpoint_freq, config.learner.n_timesteps // 10 or 1))
    t0 = time.perf_counter()
    metrics = train(config, run.path, resume=run.is_run(), show_progress=False,
                    callbacks=[TuneReport(run.path, every)], on_pretrain=PretrainReport(run.path),
                    opponent_procs=spec.get("opponent_procs", 1))
    t1 = time.perf_counter()
    specs = spec.get("policies")
    if config.side == "intruders":  # the opponent's measures against the trained intruders
        table = _evaluate_intruders(config, run, spec["episodes"], spec["eval_seed"])
    else:
        table = _evaluate(config, run, spec["episodes"], spec["eval_seed"],
                          reference_specs() if specs is None else specs)
    t2 = time.perf_counter()
    result = {"trial": trial.key, "point": trial.point, "seed": trial.seed, **trial.values, "algo": config.algo,
              "final_eval_return": metrics.get("final_eval_mean_return"),
              "best_eval_return": metrics.get("best_eval_mean_return")}
    for row in table.itertuples():
        name = LEARNED if row.policy == config.algo else row.policy
        result[f"{name}_return"] = float(row.return_mean)
        result[f"{name}_eliminated"] = float(row.eliminated_mean)
    result.update({name: metrics.get(name) for name in METRICS_COLUMNS})
    result.update(train_seconds=t1 - t0, evaluate_seconds=t2 - t1)
    storage.finish(trial.key, result, run.path)
    tune.report({**result, "phase": "done", "timesteps_total": metrics.get("timesteps")})  # Tune's step (MLflow's)


# Tune knows a function trainable by its __name__, and Tuner.restore refuses another name: saved
# experiments name this one.
run_trial.__name__ = "_run_trial"


def trial_dirname(trial) -> str:
    """Tune's folder (and name) of a trial: the trial's key."""
    return trial.config["spec"]["trial"]["key"]
