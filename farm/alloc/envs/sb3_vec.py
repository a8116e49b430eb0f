"""A gymnasium VectorEnv as stable-baselines3's VecEnv, and the batched training env's factory.

SB3VecEnv runs a gymnasium.vector.VectorEnv that autoresets in the same step (AutoresetMode
SAME_STEP, farm.alloc.envs.vector.SwarmAllocationVectorEnv's) under SB3's VecEnv conventions,
the ones DummyVecEnv follows over single envs, so PPO, SAC and TD3 learn on it as on a
DummyVecEnv of the same episodes. monitored adapts any such VectorEnv for training (SB3VecEnv
in a VecMonitor); make_vec_env makes the allocation env's batched training env so, which
training uses when n_envs > 1 (and the intruders' batched env, farm.alloc.envs.intruders, the same way).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError

__all__ = ["SB3VecEnv", "make_vec_env", "monitored"]


class SB3VecEnv(VecEnv):
    """stable-baselines3's VecEnv over a gymnasium VectorEnv with SAME_STEP autoreset.

    env: the VectorEnv (its metadata["autoreset_mode"] AutoresetMode.SAME_STEP, else a
    one-line ConfigError naming `autoreset_mode`); num_envs, observation_space and
    action_space are its num_envs and single spaces.

    step_wait() returns, as DummyVecEnv does: obs: (B, ...) the observations (a finished
    episode's replaced by its successor's first, SAME_STEP's own), rewards: (B,) float32,
    dones: (B,) bool (terminated or truncated), infos: a list of B dicts, episode k's info
    (the ended episode's, infos["final_info"], when it ended) with "TimeLimit.truncated"
    (truncated and not terminated) and, when it ended, "terminal_observation" (its last
    observation); its successor's reset info goes to reset_infos[k]. Values are Python
    numbers, as a single env gives them.

    reset() resets every episode with the seeds of seed() (episode k: seed + k, as
    DummyVecEnv seeds its env k) and the options of set_options(), both used once; options
    must be the same for every episode (a VectorEnv takes one options dict), else
    ConfigError naming `options`.

    The VectorEnv is one object holding every episode: get_attr(name) reads its attribute
    once and gives it for each index asked; set_attr and env_method act on it once and may
    only be asked for every index (ConfigError naming `indices` otherwise); env_is_wrapped
    is False for every index (no per-episode gymnasium wrappers). get_images raises
    NotImplementedError (no rendering). close() closes the VectorEnv.
    """

    def __init__(self, env: VectorEnv):
        mode = env.metadata.get("autoreset_mode")
        if mode != AutoresetMode.SAME_STEP:
            raise ConfigError(f"autoreset_mode: SB3VecEnv needs a VectorEnv that autoresets in the same step "
                              f"(AutoresetMode.SAME_STEP), got {mode!r}", field="autoreset_mode")
        self.env = env
        self._actions: np.ndarray | None = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)

    def reset(self) -> np.ndarray:
        """Reset every episode (seeds and options set before, used once); returns obs: (B, ...)."""
        options = self._options[0] or None
        if any(o != self._options[0] for o in self._options[1:]):
            raise ConfigError("options: the batched env takes one options dict for all its episodes, got "
                              "different ones", field="options")
        seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
        obs, infos = self.env.reset(seed=seeds, options=options)
        self.reset_infos = self._split(infos)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Keep the actions, (B, A), for step_wait()."""
        self._actions = actions

    def step_wait(self):
        """Step every episode; returns (obs, rewards: (B,) float32, dones: (B,) bool, infos: list of B dicts)."""
        obs, rewards, terminated, truncated, infos = self.env.step(self._actions)
        terminated, truncated = np.asarray(terminated, dtype=bool), np.asarray(truncated, dtype=bool)
        dones = terminated | truncated
        step_infos = self._split(infos)
        if dones.any():
            ended = np.flatnonzero(dones).tolist()
            final_obs = infos["final_obs"]
            for k, info in zip(ended, self._split(infos.get("final_info", {}), ended)):
                self.reset_infos[k] = step_infos[k]
                step_infos[k] = info
                info["terminal_observation"] = final_obs[k]
        for info, cut in zip(step_infos, (truncated & ~terminated).tolist()):
            info["TimeLimit.truncated"] = cut
        return obs, np.asarray(rewards, dtype=np.float32), dones, step_infos

    def _split(self, infos: dict, rows: list[int] | None = None) -> list[dict[str, Any]]:
        """gymnasium's dict of (B,) arrays with `_key` masks -> B dicts of Python values, each
        with the keys its mask marks (a nested dict of arrays, nested the same way); rows:
        only these episodes' dicts, in their order (None: all B)."""
        keys, columns, masks = [], [], []
        for key, values in infos.items():
            if key.startswith("_") or key in ("final_obs", "final_info"):
                continue
            if isinstance(values, dict):
                values = self._split(values)
            elif values.__class__ is np.ndarray and values.ndim == 1 and values.dtype.kind != "O":
                values = values.tolist()
            mask = infos.get("_" + key)
            keys.append(key)
            columns.append(values)
            masks.append(None if mask is None or mask.all() else mask.tolist())
        rows = range(self.num_envs) if rows is None else rows
        if not keys:
            return [{} for _ in rows]
        if all(mask is None for mask in masks) and len(rows) == self.num_envs:
            return [dict(zip(keys, row)) for row in zip(*columns)]
        return [{key: column[k] for key, column, mask in zip(keys, columns, masks) if mask is None or mask[k]}
                for k in rows]

    def close(self) -> None:
        """Close the VectorEnv."""
        self.env.close()

    def _all_indices(self, indices, what: str) -> list[int]:
        """indices as a list; ConfigError unless they name every episode (what: the call's name)."""
        chosen = list(self._get_indices(indices))
        if sorted(chosen) != list(range(self.num_envs)):
            raise ConfigError(f"indices: {what} acts on the batched env, which holds all {self.num_envs} episodes; "
                              f"ask it for all of them, got {chosen}", field="indices")
        return chosen

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        """The VectorEnv's attribute attr_name, once for each index asked."""
        value = getattr(self.env, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        """Set the VectorEnv's attribute attr_name (indices must name every episode)."""
        self._all_indices(indices, "set_attr")
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        """Call the VectorEnv's method once (indices must name every episode); its result for each index."""
        chosen = self._all_indices(indices, "env_method")
        result = getattr(self.env, method_name)(*method_args, **method_kwargs)
        return [result for _ in chosen]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        """False for each index: the episodes have no gymnasium wrappers."""
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        """Not available: the batched env renders nothing."""
        raise NotImplementedError("SB3VecEnv: the batched env has no render mode")


def make_vec_env(config: AllocConfig, n_envs: int, client, estimates: bool | str = False,
                 seed: int | None = None) -> VecMonitor:
    """The allocation env's batched training env: n_envs episodes of config in one
    SwarmAllocationVectorEnv (answered by client, with `estimates` as the single env's),
    adapted by SB3VecEnv and wrapped in SB3's VecMonitor (episode returns and lengths in
    infos[k]["episode"]). seed: None, or episode k's seed at the first reset is seed + k (the
    algorithm's own seed, set by SB3 when it is given one, replaces it). ConfigError naming
    `num_envs` for an n_envs that is no whole number >= 1.

    The batched env is vec.venv.env (vec the VecMonitor); its get_state and set_state save and
    restore every episode."""
    from farm.alloc.envs.vector import SwarmAllocationVectorEnv

    return monitored(SwarmAllocationVectorEnv(config, num_envs=n_envs, client=client, estimates=estimates), seed)


def monitored(env: VectorEnv, seed: int | None = None) -> VecMonitor:
    """A SAME_STEP VectorEnv as a training env: adapted by SB3VecEnv and wrapped in SB3's
    VecMonitor (episode returns and lengths in infos[k]["episode"]); seed: None, or episode k's
    seed at the first reset is seed + k. The VectorEnv is the result's venv.env."""
    adapter = SB3VecEnv(env)
    if seed is not None:
        adapter.seed(seed)
    return VecMonitor(adapter)
