"""RunState: what a checkpoint holds beside SB3's model and replay buffer, so that a resumed
run goes on exactly as an uninterrupted one (docs/training.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.vec_env import VecMonitor

from farm.alloc.envs.defenders import SwarmAllocationEnv
from farm.alloc.training.callbacks import UpdateTimer

__all__ = ["RunState"]


class RunState:
    """What a checkpoint holds beside SB3's model (with its optimisers, step count and last
    observation) and replay buffer, so that a run resumed from it goes on exactly as the run
    would have without the stop (training on the CPU is deterministic):

    - the random generators SB3 draws from, by their public getters: numpy's global one (the
      action noise, the replay buffer's samples), torch's (TD3's target smoothing noise),
      python's (SB3 seeds it) and the model's action space's (the warm-up's random actions).
      Loading a model seeds them all again (SB3's set_random_seed), so they are set after;
    - the training env's episodes in progress, generators and counters (get_state of the
      SwarmAllocationEnv, or of the batched vector env with n_envs > 1) and its monitor's
      figures of those episodes (the Monitor's rewards, the VecMonitor's returns and lengths:
      they only make the episodes' logged returns whole);
    - the eval env's state (evaluations go on drawing from its generator, seeded once at the
      start), and the periodic evaluation's history (EvalCallback's public attributes: the
      steps, returns and lengths of evaluations.npz, the best and the last mean return, and
      its call count, which decides the steps it evaluates at);
    - the wall and update seconds so far (UpdateTimer), so that metrics.json's timings
      describe the whole run: the earlier parts up to the checkpoint and the resumed part;
    - the pretraining's figures (`pretrain`: metrics.json's pretrain_* fields and
      pretrained_eval_mean_return, None for a run without pretraining), set when the
      pretraining ends: metrics.json is written only when training ends, so a run resumed
      from a checkpoint has them from there alone (a checkpoint without them: None).

    train_env, monitor: the training env (a SwarmAllocationEnv, or the batched vector env) and
    the Monitor (VecMonitor) around it; eval_env: the periodic evaluation's env; evaluation: its
    EvalCallback; timer: the run's UpdateTimer; n_envs: the episodes stepped at once."""

    def __init__(self, train_env, monitor, eval_env: SwarmAllocationEnv, evaluation: EvalCallback,
                 timer: UpdateTimer, n_envs: int = 1):
        self.train_env, self.monitor, self.eval_env = train_env, monitor, eval_env
        self.evaluation, self.timer, self.n_envs = evaluation, timer, n_envs
        self.pretrain: dict | None = None  # the pretraining's figures (see the class doc)

    def _monitor_state(self):
        m = self.monitor
        if isinstance(m, VecMonitor):
            return {"returns": m.episode_returns.copy(), "lengths": m.episode_lengths.copy(),
                    "count": m.episode_count}
        return list(m.rewards)

    def _restore_monitor(self, saved) -> None:
        m = self.monitor
        if isinstance(m, VecMonitor):
            m.episode_returns, m.episode_lengths = saved["returns"].copy(), saved["lengths"].copy()
            m.episode_count = saved["count"]
        else:
            m.rewards = list(saved)

    def capture(self, model: BaseAlgorithm) -> dict:
        """The state now, as a picklable dict (restore's input)."""
        import random

        import torch

        e = self.evaluation
        return {
            "steps": int(model.num_timesteps),
            "numpy_rng": np.random.get_state(), "torch_rng": torch.get_rng_state(), "python_rng": random.getstate(),
            "action_space_rng": model.action_space.np_random.bit_generator.state,
            "train_env": self.train_env.get_state(), "episode_rewards": self._monitor_state(),
            "eval_env": self.eval_env.get_state(),
            "evaluations": {"timesteps": list(e.evaluations_timesteps), "results": list(e.evaluations_results),
                            "ep_lengths": list(e.evaluations_length), "best_mean_reward": e.best_mean_reward,
                            "last_mean_reward": e.last_mean_reward},
            "wall_seconds": self.timer.wall_seconds, "update_seconds": self.timer.update_seconds,
            "pretrain": None if self.pretrain is None else dict(self.pretrain),
        }

    def restore(self, model: BaseAlgorithm, state: dict) -> None:
        """Put a captured state back, into a model just loaded from the same checkpoint (its
        training env reset: the Monitor accepts steps again); rewrites evaluations.npz with
        the evaluations up to the checkpoint (removes it when there were none)."""
        import random

        import torch

        self.train_env.set_state(state["train_env"])
        self._restore_monitor(state["episode_rewards"])
        self.eval_env.set_state(state["eval_env"])
        e, history = self.evaluation, state["evaluations"]
        e.evaluations_timesteps = list(history["timesteps"])
        e.evaluations_results = list(history["results"])
        e.evaluations_length = list(history["ep_lengths"])
        e.best_mean_reward, e.last_mean_reward = history["best_mean_reward"], history["last_mean_reward"]
        # a call per vector step: it evaluates where an uninterrupted run does
        e.n_calls = state["steps"] // self.n_envs
        if e.log_path is not None:  # the stopped part's later evaluations go: the resumed run redoes them
            if e.evaluations_timesteps:  # EvalCallback's own layout
                np.savez(e.log_path, timesteps=e.evaluations_timesteps, results=e.evaluations_results,
                         ep_lengths=e.evaluations_length)
            else:
                Path(e.log_path + ".npz").unlink(missing_ok=True)
        self.pretrain = state.get("pretrain")  # None from a checkpoint that holds no figures
        self.timer.earlier_wall_seconds = state["wall_seconds"]
        self.timer.update_seconds = state["update_seconds"]
        np.random.set_state(state["numpy_rng"])
        torch.set_rng_state(state["torch_rng"])
        random.setstate(state["python_rng"])
        model.action_space.np_random.bit_generator.state = state["action_space_rng"]
