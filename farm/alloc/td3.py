"""stable-baselines3's TD3 with a lean per-step path and a clock on its updates.

The algorithm is SB3's, unchanged: same networks, losses, updates, noise, replay
buffer and saved files (a model.zip loads with plain `stable_baselines3.TD3`).
At batch 1 SB3's per-step bookkeeping costs more than the network itself, so:
- action selection runs the actor's layers (Linear, ReLU, Tanh) in numpy on
  views of its float32 CPU parameters, which the optimizer updates in place,
  instead of going through `predict()`; the views are rebuilt when a parameter's
  storage moves, and any other layer, observation kind or device uses torch;
- switching between training and evaluation mode, which walks every module of
  actor and critic twice per step, is skipped when no module's behaviour depends
  on the mode (no dropout, no batch norm);
- `LeanVecEnv`, for envs that return a fresh observation array and info dict
  from every step (as SwarmAllocationEnv does), steps them without deep-copying
  both again;
- `update_seconds` accumulates the wall time of the gradient updates
  (`train()`), so a run reports the share of its time spent outside them.
"""

from __future__ import annotations

import functools
import time

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3 import TD3
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.vec_env import DummyVecEnv

__all__ = ["AllocTD3", "LeanVecEnv"]

_MODE_FREE = (torch.nn.Linear, torch.nn.ReLU, torch.nn.Tanh, torch.nn.Flatten, torch.nn.Sequential,
              torch.nn.ModuleList, torch.nn.Identity, FlattenExtractor)


def _mode_free(module: torch.nn.Module) -> bool:
    """True when module.train(mode) changes nothing but flags: every submodule is a
    known mode-free layer or one of SB3's containers (which never read the flag)."""
    from stable_baselines3.common.policies import BaseModel

    return all(isinstance(m, (*_MODE_FREE, BaseModel)) for m in module.modules())


def _set_flags_only(policy, mode: bool) -> None:
    policy.training = mode


class AllocTD3(TD3):
    update_seconds: float = 0.0

    def _setup_model(self) -> None:
        super()._setup_model()
        if _mode_free(self.policy):
            self.policy.set_training_mode = functools.partial(_set_flags_only, self.policy)
        self._actor_plan = self._plan_numpy_actor()
        self._actor_views: list | None = None
        space = self.action_space
        self._unit_box = isinstance(space, spaces.Box) and bool(np.all(space.low == -1) and np.all(space.high == 1))

    def _plan_numpy_actor(self) -> list | None:
        """[(kind, Linear or None)] of the actor's layers, or None when the numpy path does
        not apply: Flatten -> (Linear | ReLU | Tanh)* on a non-image Box, on the CPU."""
        actor = self.actor
        if self.device.type != "cpu" or not isinstance(actor.features_extractor, FlattenExtractor) or \
                not isinstance(self.observation_space, spaces.Box) or is_image_space(self.observation_space):
            return None
        plan = []
        for m in actor.mu:
            if isinstance(m, torch.nn.Linear) and m.bias is not None:
                plan.append(("linear", m))
            elif type(m) in (torch.nn.ReLU, torch.nn.Tanh):
                plan.append((type(m).__name__.lower(), None))
            else:
                return None
        return plan

    def _numpy_views(self) -> list | None:
        """[(kind, weight (out, in), bias (out,))] numpy views sharing the parameters'
        storage, rebuilt when a storage moved; None when a parameter is not float32 on CPU."""
        linears = [m for kind, m in self._actor_plan if m is not None]
        ptrs = [(m.weight.data_ptr(), m.bias.data_ptr()) for m in linears]
        if self._actor_views is None or ptrs != self._actor_ptrs:
            if any(p.device.type != "cpu" or p.dtype != torch.float32 for m in linears for p in (m.weight, m.bias)):
                return None
            self._actor_views = [(kind, None, None) if m is None else
                                 (kind, m.weight.detach().numpy(), m.bias.detach().numpy())
                                 for kind, m in self._actor_plan]
            self._actor_ptrs = ptrs
        return self._actor_views

    def _actor_forward(self, obs: np.ndarray) -> np.ndarray:
        """obs (n_envs, *obs_shape) -> actor output (n_envs, *action_shape) float32 in [-1, 1]."""
        views = self._numpy_views() if self._actor_plan is not None else None
        if views is None:
            with torch.no_grad():
                x = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
                return self.actor(x).cpu().numpy().reshape((-1, *self.action_space.shape))
        x = np.asarray(obs, dtype=np.float32).reshape(len(obs), -1)
        for kind, w, b in views:
            if kind == "linear":
                x = x @ w.T + b
            elif kind == "relu":
                x = np.maximum(x, 0)
            else:
                x = np.tanh(x)
        return x.reshape((-1, *self.action_space.shape))

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        t0 = time.perf_counter()
        super().train(gradient_steps, batch_size)
        self.update_seconds += time.perf_counter() - t0

    def _sample_action(self, learning_starts: int, action_noise=None, n_envs: int = 1):
        """As OffPolicyAlgorithm._sample_action: (action for the env, action for the
        buffer), both (n_envs, *action_shape); the actor's tanh output is already the
        scaled action."""
        if self.num_timesteps < learning_starts or not isinstance(self.action_space, spaces.Box):
            return super()._sample_action(learning_starts, action_noise, n_envs)
        scaled = self._actor_forward(self._last_obs)
        if action_noise is not None:
            scaled = np.minimum(np.maximum(scaled + action_noise(), -1), 1)
        return (scaled.copy() if self._unit_box else self.policy.unscale_action(scaled)), scaled

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "update_seconds", "_actor_plan", "_actor_views", "_actor_ptrs",
                "_unit_box"]


class LeanVecEnv(DummyVecEnv):
    """DummyVecEnv's step without its deep copies, for Box-observation envs whose step
    returns a new observation array and a new info dict each call."""

    def __init__(self, env_fns):
        super().__init__(env_fns)
        if self.keys != [None]:
            raise ValueError("LeanVecEnv: only Box observation spaces")

    def step_wait(self):
        """-> obs (n_envs, *obs_shape), rewards (n_envs,) float32, dones (n_envs,) bool, infos."""
        for i, env in enumerate(self.envs):
            obs, self.buf_rews[i], terminated, truncated, info = env.step(self.actions[i])
            self.buf_dones[i] = terminated or truncated
            info["TimeLimit.truncated"] = truncated and not terminated
            if self.buf_dones[i]:
                info["terminal_observation"] = obs
                obs, self.reset_infos[i] = env.reset()
            self.buf_infos[i] = info
            self.buf_obs[None][i] = obs
        return self.buf_obs[None].copy(), self.buf_rews.copy(), self.buf_dones.copy(), list(self.buf_infos)
