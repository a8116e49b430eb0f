"""A `farm train` run logged to MLflow (the config's `tracking.mlflow`, farm.core.tracking):
MlflowRun opens (or, on --resume, reopens) the run's MLflow run, logs the config as params,
the periodic evaluation's curve as it grows (its EvalLogger, given to the run's EvalCallback
as SB3's callback_after_eval: eval/mean_return, eval/std_return, eval/mean_ep_length at step= the
timestep), and at the end metrics.json's numbers and the run's files as artifacts.

It reads the training's public state only (EvalCallback's history) and draws no random
number, so a tracked run computes what an untracked one does; and MLflow failing while the run
goes on (its store damaged or made read-only, its server gone) is one warning, and the run goes
on untracked and finishes as an untracked one (farm.core.tracking.Guard). This module imports
mlflow when a run is opened; train() imports it only when tracking is configured.
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

from stable_baselines3.common.callbacks import BaseCallback

from farm.alloc.training.runs import CONFIG, EVALUATIONS, METRICS, MODEL
from farm.core.tracking import CHECK_HTTP, Guard, TrackingWarning, flat_params, mlflow_http, open_experiment, refused

__all__ = ["MlflowRun", "EvalLogger", "RUN_FILE", "EVAL_METRICS"]

RUN_FILE = "mlflow_run.json"  # in the run folder: the MLflow run a resumed run goes on logging into
EVAL_METRICS = ("eval/mean_return", "eval/std_return", "eval/mean_ep_length")
# The run folder's files logged as artifacts when they exist (farm.alloc.training.runs' module doc).
ARTIFACTS = (MODEL, METRICS, CONFIG, EVALUATIONS, "training_curve.png", "eval_table.csv", "eval_episodes.csv",
             "eval_steps.csv", "eval_table_games.csv", "fidelity_differences.csv")
_BATCH = 100  # MLflow's most params in one log_batch


class MlflowRun:
    """One training run's MLflow run (open it with MlflowRun.open). client: an MlflowClient;
    run_id: the MLflow run's id. Its calls while the run goes on go through guard (a Guard): the
    first that fails turns tracking off for the rest of the run, with one TrackingWarning."""

    def __init__(self, client, run_id: str):
        self.client, self.run_id = client, run_id
        self.logged_steps: set[int] = {int(m.step) for m in client.get_metric_history(run_id, EVAL_METRICS[0])}
        self.eval_logger = EvalLogger(self)  # the run's EvalCallback's callback_after_eval (its parent then)
        self.guard = Guard("the run", on_off=lambda: client.set_terminated(run_id, "FAILED"))

    @classmethod
    def open(cls, config, run_dir, resume: bool) -> MlflowRun:
        """The MLflow run of config (a TrainConfig with tracking.mlflow set) training into
        run_dir: on resume the one run_dir's RUN_FILE names (when it is on the same tracking
        URI and not deleted), else a new one (its id written to RUN_FILE); the config's params
        not logged yet are logged (a resume's changed length or threads keep their first value).
        ConfigError, one line naming tracking.mlflow.tracking_uri, when the URI cannot work
        (farm.core.tracking.open_experiment: checked before any work, the capture-time store
        refused as a tracking store) or MLflow fails here."""
        from farm.alloc.training.config import store_of

        params = config.tracking.mlflow
        client, experiment_id = open_experiment(params, config.name, store=store_of(config))
        with mlflow_http(CHECK_HTTP), refused(params.tracking_uri):
            return cls._open(client, experiment_id, config, Path(run_dir), resume)

    @classmethod
    def _open(cls, client, experiment_id: str, config, run_dir: Path, resume: bool) -> MlflowRun:
        from mlflow.entities import Param
        from mlflow.exceptions import MlflowException

        params = config.tracking.mlflow
        saved = _read_run_file(run_dir / RUN_FILE) if resume else None
        run = None
        if saved is not None and saved.get("tracking_uri") == params.tracking_uri:
            try:
                run = client.get_run(saved["run_id"])
            except MlflowException:
                run = None
            if run is not None and run.info.lifecycle_stage != "active":
                run = None
        if run is None:
            run = client.create_run(experiment_id, run_name=config.name,
                                    tags={"farm.kind": "train", "farm.run_dir": str(run_dir.resolve()),
                                          "farm.algo": config.algo})
            from farm.core.output import atomic_write_bytes

            run_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(run_dir / RUN_FILE, (json.dumps(
                {"tracking_uri": params.tracking_uri, "experiment_id": experiment_id,
                 "run_id": run.info.run_id}, indent=2) + "\n").encode())
        else:
            client.update_run(run.info.run_id, status="RUNNING")
        values = json.loads(config.model_dump_json(exclude={"tracking"}))
        new = [Param(k, v) for k, v in flat_params(values).items() if k not in run.data.params]
        for i in range(0, len(new), _BATCH):
            client.log_batch(run.info.run_id, params=new[i:i + _BATCH])
        return cls(client, run.info.run_id)

    @property
    def evaluation(self):
        """The run's EvalCallback: the one eval_logger was given to (None before)."""
        return self.eval_logger.parent

    def log_evaluations(self) -> None:
        """Log the evaluation's points not logged yet (by step: a resumed run's redone
        evaluations, the same numbers, are not logged twice); never raises (guard)."""
        e = self.evaluation
        step = int(e.evaluations_timesteps[-1]) if e is not None and e.evaluations_timesteps else 0
        self.guard(f"logging the evaluation of step {step}", self._log_evaluations)

    def _log_evaluations(self) -> None:
        import numpy as np
        from mlflow.entities import Metric

        e = self.evaluation
        if e is None:
            return
        metrics = []
        now = _now_ms()
        for step, returns, lengths in zip(e.evaluations_timesteps, e.evaluations_results, e.evaluations_length):
            step = int(step)
            if step in self.logged_steps:
                continue
            values = (float(np.mean(returns)), float(np.std(returns)), float(np.mean(lengths)))
            metrics += [Metric(key, value, now, step) for key, value in zip(EVAL_METRICS, values)]
            self.logged_steps.add(step)
        if metrics:
            self.client.log_batch(self.run_id, metrics=metrics)

    def finish(self, metrics: dict, run_dir) -> None:
        """The run has trained: the rest of the curve, metrics.json's numbers (at step= its
        timesteps), the run folder's files (ARTIFACTS, and the curve as evaluations.csv), then
        the MLflow run ends FINISHED; never raises (guard)."""
        self.log_evaluations()
        self.guard("logging the run's metrics and files", self._finish, metrics, run_dir)

    def _finish(self, metrics: dict, run_dir) -> None:
        from mlflow.entities import Metric

        self._log_evaluations()
        step, now = int(metrics.get("timesteps") or 0), _now_ms()
        numbers = [Metric(k, float(v), now, step) for k, v in metrics.items()
                   if isinstance(v, (int, float)) and not isinstance(v, bool)]
        self.client.log_batch(self.run_id, metrics=numbers)
        run_dir = Path(run_dir)
        for name in ARTIFACTS:
            if (run_dir / name).is_file():
                self.client.log_artifact(self.run_id, str(run_dir / name))
        curve = _curve_csv(self.evaluation)
        if curve is not None:
            self.client.log_text(self.run_id, curve, "evaluations.csv")
        self.client.set_terminated(self.run_id, "FINISHED")

    def end(self, status: str) -> None:
        """End the MLflow run with status (FAILED, KILLED) after the training stopped; a
        failure of MLflow itself then is not raised (the training's error is the one to see)."""
        if self.guard.off:
            return
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TrackingWarning)  # the training's own error is being raised
            self.guard(f"ending the run {status}", self._end, status)

    def _end(self, status: str) -> None:
        self._log_evaluations()
        self.client.set_terminated(self.run_id, status)


class EvalLogger(BaseCallback):
    """SB3's callback_after_eval of the run's EvalCallback: after each evaluation, logs the
    new points of its history to MLflow (MlflowRun.log_evaluations)."""

    def __init__(self, run: MlflowRun):
        super().__init__()
        self.run = run

    def _on_step(self) -> bool:
        self.run.log_evaluations()
        return True


def _now_ms() -> int:
    import time

    return int(time.time() * 1000)


def _read_run_file(path: Path) -> dict | None:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("run_id"), str) else None


def _curve_csv(evaluation) -> str | None:
    """The evaluation's curve as CSV text (timesteps, mean_return, std_return, mean_ep_length,
    episodes), None without evaluations."""
    import numpy as np

    if evaluation is None or not evaluation.evaluations_timesteps:
        return None
    out = io.StringIO()
    out.write("timesteps,mean_return,std_return,mean_ep_length,episodes\n")
    for step, returns, lengths in zip(evaluation.evaluations_timesteps, evaluation.evaluations_results,
                                      evaluation.evaluations_length):
        out.write(f"{int(step)},{float(np.mean(returns))!r},{float(np.std(returns))!r},"
                  f"{float(np.mean(lengths))!r},{len(returns)}\n")
    return out.getvalue()
