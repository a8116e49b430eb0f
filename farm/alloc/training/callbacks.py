"""The SB3 callbacks of a training run, each through SB3's public callback hooks: UpdateTimer
(the gradient updates' wall time), DivergenceGuard (stops a run whose losses, parameters or
actions are not finite), StepProgress (a progress bar), AfterUpdates (act when the steps pass
a multiple, after that step's update) and Checkpointer (the exact-resume checkpoints)."""

from __future__ import annotations

import math
import pickle
import time
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from farm.alloc.training.runs import STATE_MAGIC, checkpoint_files
from farm.core.errors import TrainingDiverged

__all__ = ["UpdateTimer", "DivergenceGuard", "StepProgress", "AfterUpdates", "Checkpointer"]


class UpdateTimer(BaseCallback):
    """Times the training and its gradient updates through SB3's public callback hooks: an
    off-policy algorithm calls train() between a rollout's end and the next rollout's start
    (or the end of training), so those intervals add up to the update time (`update_seconds`);
    `wall_seconds` runs from the training's start to its end. A resumed run starts them at
    its checkpoint's figures (RunState), so that both describe the whole run."""

    def __init__(self):
        super().__init__()
        self.update_seconds = 0.0
        self.earlier_wall_seconds = 0.0  # a resumed run's parts before its checkpoint
        self._rollout_end: float | None = None
        self._start: float | None = None
        self._end: float | None = None

    @property
    def wall_seconds(self) -> float:
        """The training's wall seconds so far (to its end once ended), earlier parts included."""
        if self._start is None:
            return self.earlier_wall_seconds
        return self.earlier_wall_seconds + (self._end or time.perf_counter()) - self._start

    def _on_training_start(self) -> None:
        self._start, self._end = time.perf_counter(), None

    def _on_rollout_end(self) -> None:
        self._rollout_end = time.perf_counter()

    def _on_rollout_start(self) -> None:
        self._close()

    def _on_training_end(self) -> None:
        self._close()
        self._end = time.perf_counter()

    def _close(self) -> None:
        if self._rollout_end is not None:
            self.update_seconds += time.perf_counter() - self._rollout_end
            self._rollout_end = None

    def _on_step(self) -> bool:
        return True


class DivergenceGuard(BaseCallback):
    """Stops a run that diverges, through SB3's public callback hooks: the actions of every
    step (`self.locals`), and after every training phase (at the next rollout's start and
    at the end of training) the logger's actor and critic losses and every parameter of
    the policy (actor, critics and their targets) must be finite; else TrainingDiverged
    names the step. It reads and changes nothing of the training (no random numbers)."""

    LOSSES = ("train/actor_loss", "train/critic_loss", "train/ent_coef_loss", "train/policy_gradient_loss",
              "train/value_loss", "train/loss")  # TD3's and SAC's, SAC's, PPO's

    def _on_training_start(self) -> None:
        self._check("in the policy it starts from")

    def _on_step(self) -> bool:
        actions = self.locals.get("actions")
        if actions is not None and not np.all(np.isfinite(actions)):
            raise TrainingDiverged(f"training diverged at step {self.num_timesteps}: the policy's action is not "
                                   f"finite (lower the learning_rate?)")
        return True

    def _on_rollout_start(self) -> None:
        self._check("after the update")

    def _on_training_end(self) -> None:
        self._check("after the update")

    def _check(self, what: str) -> None:
        import torch

        for name in self.LOSSES:
            value = self.logger.name_to_value.get(name)
            if value is not None and not math.isfinite(value):
                raise TrainingDiverged(f"training diverged at step {self.num_timesteps}: {name} is {value} "
                                       f"{what} (lower the learning_rate?)")
        with torch.no_grad():  # one sum per tensor is fast; a sum that is not finite is looked into
            params = list(self.model.policy.named_parameters())
            sums = torch.stack([p.sum() for _, p in params])
            if bool(torch.isfinite(sums).all()):
                return
            for name, p in params:
                if not bool(torch.isfinite(p).all()):
                    raise TrainingDiverged(f"training diverged at step {self.num_timesteps}: the policy's {name} "
                                           f"is not finite {what} (lower the learning_rate?)")


class StepProgress(BaseCallback):
    """A progress bar of environment steps with steps/s and ETA."""

    def __init__(self, total: int, done: int, enabled: bool):
        super().__init__()
        self.total, self.done, self.enabled = total, done, enabled

    def _on_training_start(self) -> None:
        from farm.core.progress import GameProgress

        self.bar = GameProgress(self.total, self.done, enabled=self.enabled, desc="steps", unit="step")
        self.last = self.num_timesteps

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self.last)
        self.last = self.num_timesteps
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


class AfterUpdates(BaseCallback):
    """An SB3 callback acting each time the steps pass a multiple of `every`, after that step's
    gradient update: an off-policy algorithm updates between a rollout's end and the next
    rollout's start, so it acts at a rollout's start and at the end of training (`due(steps)`,
    the subclass's action). last: the steps it last acted at (a resumed run's checkpoint)."""

    def __init__(self, every: int, last: int = 0):
        super().__init__()
        self.every, self.last = max(1, int(every)), int(last)

    def due(self, steps: int) -> None:
        """Act at `steps` (a subclass's)."""
        raise NotImplementedError

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        self._act_when_due()

    def _on_training_end(self) -> None:
        self._act_when_due()

    def _act_when_due(self) -> None:
        steps = int(self.model.num_timesteps)
        if steps // self.every > self.last // self.every:
            self.due(steps)
            self.last = steps


class Checkpointer(AfterUpdates):
    """Saves a checkpoint (checkpoint_files: the model, the replay buffer, then the RunState)
    each time the steps pass a multiple of `every`, after that step's gradient update
    (AfterUpdates), a state an uninterrupted run goes on from. (SB3's CheckpointCallback saves
    in on_step, before the step's update and before the step's transition enters the replay
    buffer; a run resumed from it went on without them.)

    run_dir: the run folder; every: steps between checkpoints; state: the run's RunState;
    saved: the steps of the checkpoint the run resumed from (0 for a new run)."""

    def __init__(self, run_dir: Path, every: int, state, saved: int = 0):
        super().__init__(every, saved)
        self.run_dir, self.state = Path(run_dir), state

    def due(self, steps: int) -> None:
        """Save the checkpoint of `steps`: the RunState last, sealed (farm.core.sealed, STATE_MAGIC)
        with the SHA-256 of the model's and the replay buffer's files in its header."""
        from farm.core.output import atomic_write_bytes
        from farm.core.sealed import file_sha256, seal

        model_file, buffer_file, state_file = checkpoint_files(self.run_dir, steps)
        model_file.parent.mkdir(parents=True, exist_ok=True)
        self.model.save(model_file)
        files = [model_file]
        if getattr(self.model, "replay_buffer", None) is not None:  # off-policy; PPO's rollouts start afresh
            self.model.save_replay_buffer(buffer_file)
            files.append(buffer_file)
        payload = pickle.dumps(self.state.capture(self.model))
        atomic_write_bytes(state_file, seal(STATE_MAGIC, payload, files={p.name: file_sha256(p) for p in files}))
