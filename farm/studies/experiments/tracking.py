"""An experiment's trials logged to MLflow from the driver: TrialRuns, a Ray Tune
LoggerCallback (Tune's public callback API) writing through MLflow's public client.

Every trial is one MLflow run, named after the trial (`p0_s1`) and tagged with it
(`farm.trial`), with the experiment's storage (`farm.storage`) and with the experiment's
instance (`farm.instance`, drawn when the experiment starts and kept in Tune's state with this
callback, so an experiment made again in the same folder logs into runs of its own). Its params are the trial's
config flattened by "/" (`spec/trial/seed`, `spec/trial/config/env/c_capture`, ...), its
metrics each report's numbers (bools as 0/1, the config left out: it is in the params) at
step = the report's `timesteps_total`, else its `training_iteration`. MLflow failing while the
experiment goes on is one warning, and the experiment goes on untracked: a Tune callback that
raised would stop it (farm.core.tracking.Guard).

Why not Ray's MLflowLoggerCallback: TrialRuns' docstring.
"""

from __future__ import annotations

import numbers
import time
import uuid

import numpy as np
from ray.tune.logger import LoggerCallback

from farm.core.tracking import (
    Guard,
    MlflowParams,
    flattened,
    mlflow_client,
    mlflow_experiment,
    param_text,
)

__all__ = ["TrialRuns", "report_metrics"]

_MAX_PARAMS = 100  # MLflow's most params in one log_batch
_MAX_METRICS = 1000  # and most metrics


def report_metrics(result: dict) -> dict[str, float]:
    """A Tune report's numbers as MLflow metrics: flattened by "/", bools as 0/1, its config
    and what is not a real number (text, None, lists) left out."""
    values = flattened({k: v for k, v in result.items() if k != "config"}, "/")
    return {key: float(value) for key, value in values.items() if isinstance(value, (numbers.Real, np.bool_))}


class TrialRuns(LoggerCallback):
    """One MLflow run a trial (the module doc). params: where (MlflowParams); experiment: the
    MLflow experiment's name (made by the caller, farm.core.tracking.mlflow_experiment, before
    Ray starts); storage: the experiment's storage (its folder or URI), a tag that tells this
    experiment's runs from another's of the same trial names; tags: added to every run. Its
    instance (a random hex id, the `farm.instance` tag) tells this experiment's runs from those of
    an earlier one made in the same storage and since deleted; a restored experiment has it back
    with this callback from Tune's state.

    Why not Ray's MLflowLoggerCallback: it writes every param and every metric of a report in a
    call of its own, which on an SQLite store is a transaction each, spent in Tune's controller
    loop while the trials wait for it (docs/results.md times both); TrialRuns writes a report in
    one `log_batch`. It also finds a trial's run again: a trial that runs again after the driver
    was restarted (`farm experiments` run again on the same folder) goes on logging into the run
    it had, found by its tags, whatever that run's status (a trial that had finished when the
    driver was killed, before Tune saved its state, is started again by Tune's restore and
    returns its result at once: it reopens its run, it does not open a second), where Ray's
    logger, whose trial-to-run map lives only in the driver's memory, opened a second one. It
    changes no process-wide MLflow setting. Tune saves its callbacks with the experiment's
    state, so TrialRuns pickles without its client. Every call to MLflow goes through its guard
    (a Guard): the first that fails turns tracking off for the rest of the experiment with one
    TrackingWarning, and no callback raises (Tune would stop the experiment).
    """

    def __init__(self, params: MlflowParams, experiment: str, storage: str, tags: dict[str, str]):
        self.params, self.experiment, self.storage = params, experiment, storage
        self.instance = uuid.uuid4().hex
        self.tags = {**tags, "farm.storage": storage, "farm.instance": self.instance}
        self._client = None
        self._experiment_id: str | None = None
        self._runs: dict[str, str] = {}  # trial name -> MLflow run id
        self.guard = Guard("the experiment")

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_client": None, "_runs": {}, "guard": Guard("the experiment")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({"guard": Guard("the experiment"), **state})  # a logger pickled without one

    @property
    def client(self):
        """The MlflowClient of params (made on first use, the experiment's id with it)."""
        if self._client is None:
            self._client = mlflow_client(self.params)
            self._experiment_id = mlflow_experiment(self._client, self.params, self.experiment)
        return self._client

    def _found(self, name: str):
        """This experiment's run of the trial, whatever its status, when there is one (a trial run
        again). Trial names are the plan's keys (p0_s1) and the instance is hex: safe in a filter;
        the storage is compared here."""
        runs = self.client.search_runs(
            [self._experiment_id],
            filter_string=f"tags.`farm.trial` = '{name}' and tags.`farm.instance` = '{self.instance}'",
            order_by=["attributes.start_time DESC"])
        mine = [r for r in runs if r.data.tags.get("farm.storage") == self.storage]
        return mine[0] if mine else None

    def log_trial_start(self, trial) -> None:
        """The trial's run: its run of this experiment (a trial run again, reopened), else a new
        one; the config's params it has not logged yet, in batches. Never raises (guard)."""
        self.guard(f"opening trial {trial}'s run", self._start, trial)

    def _start(self, trial) -> None:
        from mlflow.entities import Param

        name = str(trial)
        if name in self._runs:
            return
        run = self._found(name)
        if run is None:
            run = self.client.create_run(self._experiment_id, run_name=name, tags={**self.tags, "farm.trial": name})
            logged = {}
        else:
            self.client.update_run(run.info.run_id, status="RUNNING")
            logged = run.data.params
        self._runs[name] = run.info.run_id
        new = [Param(k, param_text(str(v))) for k, v in flattened(trial.config, "/").items() if k not in logged]
        for i in range(0, len(new), _MAX_PARAMS):
            self.client.log_batch(run.info.run_id, params=new[i:i + _MAX_PARAMS])

    def log_trial_result(self, iteration: int, trial, result: dict) -> None:
        """The report's numbers (report_metrics) in one log_batch, at its step (the module doc).
        Never raises (guard)."""
        self.guard(f"logging trial {trial}'s report", self._result, trial, result)

    def _result(self, trial, result: dict) -> None:
        from mlflow.entities import Metric

        if str(trial) not in self._runs:
            self._start(trial)
        step = int(result.get("timesteps_total") or result.get("training_iteration") or 0)
        now = int(time.time() * 1000)
        metrics = [Metric(k, v, now, step) for k, v in report_metrics(result).items()]
        for i in range(0, len(metrics), _MAX_METRICS):
            self.client.log_batch(self._runs[str(trial)], metrics=metrics[i:i + _MAX_METRICS])

    def log_trial_end(self, trial, failed: bool = False) -> None:
        """The trial's run ends FINISHED, or FAILED. Never raises (guard)."""
        run_id = self._runs.pop(str(trial), None)
        if run_id is not None:
            self.guard(f"ending trial {trial}'s run", lambda: self.client.set_terminated(
                run_id, "FAILED" if failed else "FINISHED"))
