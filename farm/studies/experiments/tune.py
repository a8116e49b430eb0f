"""The Ray Tune side of farm.studies.experiments: the SB3 callback a trial reports through, and the
Tune callback showing the experiment's progress.

This module imports Ray at its top, so it is imported only inside functions, after
farm.runtime.ray_cluster has set Ray's loopback switch (farm/runtime/cluster.py), as
farm/service/actor.py is. Both classes live at a module's top level so that Tune's pickled
experiment state names them (a restored experiment finds them by name).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from ray import tune

from farm.alloc.training import AfterUpdates

__all__ = ["TuneReport", "Progress"]


class PretrainReport:
    """A trial's pretraining progress to Ray Tune (train's on_pretrain): {"phase": "pretrain",
    "pretrain_episodes", "pretrain_episodes_total"} at step 0, the experiment's display showing
    it; once an iteration is saved, with a Tune checkpoint of the run folder holding that
    iteration (progress.json: {"timesteps": 0, "pretrain_iteration": i}; storage.checkpoint_run),
    so a trial restarted on another node, or whose local folder was lost, goes on pretraining
    after that iteration (storage.restore_run) rather than from the start. run_dir: the trial's
    run folder."""

    def __init__(self, run_dir):
        self.run_dir = Path(run_dir)

    def __call__(self, episodes: int, total: int, saved: int | None) -> None:
        """Report the pretraining's progress to Tune: episodes of total labelled so far, and when
        iteration `saved` is saved (saved not None), a checkpoint of the run folder with it."""
        from farm.studies.experiments.storage import checkpoint_run

        metrics = {"phase": "pretrain", "pretrain_episodes": episodes, "pretrain_episodes_total": total,
                   "timesteps_total": 0}
        if saved is None:
            tune.report(metrics)
            return
        with tempfile.TemporaryDirectory(prefix="farm-trial-") as folder:  # Tune copies it before report returns
            (Path(folder) / "progress.json").write_text(json.dumps({"timesteps": 0, "pretrain_iteration": saved}))
            checkpoint_run(self.run_dir, None, Path(folder))
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(folder))


class TuneReport(AfterUpdates):
    """An SB3 callback reporting a trial's steps to Ray Tune each time they pass a multiple
    of `every` ({"timesteps": n, "phase": "train"}), after the step's update (AfterUpdates),
    with a Tune checkpoint when the run's Checkpointer (called before it) has just saved one.
    The checkpoint holds everything the trial's resume needs: progress.json (the steps) and
    the run folder with that checkpoint's model, replay buffer and RunState, its evaluation
    history, best model, pretraining and config (storage.checkpoint_run). Tune uploads it to
    the experiment's storage, and a restarted trial writes its run folder again from it
    (storage.restore_run), on whatever node it runs.

    run_dir: the trial's run folder; every: steps between reports."""

    def __init__(self, run_dir, every: int):
        super().__init__(every)
        self.run_dir = Path(run_dir)

    def _on_training_start(self) -> None:
        self.last = int(self.model.num_timesteps)  # a resumed run reported its checkpoint's steps before

    def due(self, steps: int) -> None:
        """Report `steps`, with the checkpoint of `steps` when there is one."""
        from farm.alloc.training.runs import latest_checkpoint
        from farm.studies.experiments.storage import checkpoint_run

        metrics = {"timesteps": steps, "timesteps_total": steps, "phase": "train"}  # timesteps_total: Tune's step
        last = latest_checkpoint(self.run_dir, replay_buffer=getattr(self.model, "replay_buffer", None) is not None)
        if last is None or last[1] != steps:
            tune.report(metrics)
            return
        with tempfile.TemporaryDirectory(prefix="farm-trial-") as folder:  # Tune copies it before report returns
            (Path(folder) / "progress.json").write_text(json.dumps({"timesteps": steps}))
            checkpoint_run(self.run_dir, steps, Path(folder))
            tune.report(metrics, checkpoint=tune.Checkpoint.from_directory(folder))


class Progress(tune.Callback):
    """Feeds the running experiment's display (farm.studies.experiments.display.PROGRESS["display"]): trials
    done, running and waiting, steps and the ETA on stderr. Holds no state of its own, so the
    copy Tune unpickles on a restore shows the new run's display."""

    @staticmethod
    def _display():
        from farm.studies.experiments.display import PROGRESS

        return PROGRESS.get("display")

    @staticmethod
    def _key(trial) -> str:
        return trial.config["spec"]["trial"]["key"]

    def on_trial_start(self, iteration, trials, trial, **info):
        """A trial started (or restarted)."""
        display = self._display()
        if display is not None:
            display.started(self._key(trial))

    def on_trial_result(self, iteration, trials, trial, result, **info):
        """A trial reported."""
        display = self._display()
        if display is not None:
            display.result(self._key(trial), result)

    def on_trial_complete(self, iteration, trials, trial, **info):
        """A trial finished."""
        display = self._display()
        if display is not None:
            display.ended(self._key(trial), True)

    def on_trial_error(self, iteration, trials, trial, **info):
        """A trial failed for good (FailureConfig's retries spent)."""
        display = self._display()
        if display is not None:
            display.ended(self._key(trial), False)
