"""The running experiment's progress on stderr: trials done, running and waiting, the
pretraining trials' share of their episodes labelled, steps and the ETA (Display), fed by the
Tune callback farm.studies.experiments.tune.Progress."""

from __future__ import annotations

import threading

__all__ = ["Display", "PROGRESS"]

# The running experiment's display: the Tune callback (farm.studies.experiments.tune.Progress, pickled
# with Tune's state and unpickled on a restore) finds it here, so a restored experiment shows
# this run's progress.
PROGRESS: dict = {}


class Display:
    """Trials done, running and waiting, steps done and the ETA (tqdm's, over the steps this run
    trains), as a bar of steps on stderr; a trial in its pretraining is shown by the share of its
    pretraining episodes labelled (`p0_s1 pretraining 43%`), its steps not begun. finished: the
    keys of trials finished before this run."""

    def __init__(self, plan, enabled: bool, finished: list[str]):
        from farm.alloc.training.config import TrainConfig
        from farm.core.progress import GameProgress

        self.total = {t.key: TrainConfig(**t.config).learner.n_timesteps for t in plan.trials}
        self.steps = {key: (self.total[key] if key in finished else 0) for key in self.total}
        self.done: set[str] = set(finished)
        self.running: set[str] = set()
        self.failed: set[str] = set()
        self.started_keys: set[str] = set()  # trials Tune started in this run
        self.pretraining: dict[str, float] = {}  # trial -> share of its pretraining episodes labelled
        self.lock = threading.Lock()
        self.bar = GameProgress(sum(self.total.values()), sum(self.steps.values()), enabled=enabled, desc="trials",
                                unit="step")
        self._describe()

    def _set_steps(self, key: str, steps: int) -> None:
        steps = min(int(steps), self.total[key])
        if steps > self.steps[key]:
            self.bar.update(steps - self.steps[key])
            self.steps[key] = steps

    def _describe(self) -> None:
        if self.bar.bar is not None:
            self.bar.bar.set_description_str(self.description())

    def description(self) -> str:
        """The bar's text: `trials: 0/3 done, 2 running, 1 waiting; p0_s0 pretraining 43%`."""
        pending = len(self.total) - len(self.done) - len(self.running) - len(self.failed)
        failed = f", {len(self.failed)} failed" if self.failed else ""
        shares = ", ".join(f"{key} pretraining {share:.0%}" for key, share in sorted(self.pretraining.items()))
        return (f"trials: {len(self.done)}/{len(self.total)} done, {len(self.running)} running, {pending} waiting"
                f"{failed}{'; ' + shares if shares else ''}")

    def started(self, key: str) -> None:
        """A trial started (or restarted)."""
        with self.lock:
            self.running.add(key)
            self.started_keys.add(key)
            self._describe()

    def result(self, key: str, result: dict) -> None:
        """A trial reported."""
        with self.lock:
            if result.get("phase") == "pretrain" and result.get("pretrain_episodes_total"):
                self.pretraining[key] = result["pretrain_episodes"] / result["pretrain_episodes_total"]
            else:
                self.pretraining.pop(key, None)
            if "timesteps" in result and result["timesteps"] is not None:
                self._set_steps(key, result["timesteps"])
            self.running.add(key)
            self._describe()

    def ended(self, key: str, ok: bool) -> None:
        """A trial finished (ok) or failed."""
        with self.lock:
            self.running.discard(key)
            self.pretraining.pop(key, None)
            if ok:
                self._set_steps(key, self.total[key])
                self.done.add(key)
            else:
                self.failed.add(key)
            self._describe()

    def close(self) -> None:
        """Close the bar."""
        self.bar.close()


