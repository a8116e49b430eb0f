"""Labelled episodes, pretraining's data (farm.alloc.training.dagger.loop): episodes played by a
mixture of an expert and a learner, every state labelled with the expert's action."""

from __future__ import annotations

import numpy as np

from farm.alloc.envs.defenders import SwarmAllocationEnv

__all__ = ["FIELDS", "play_labelled", "concat"]

FIELDS = ("obs", "labels", "actions", "rewards", "next_obs", "terminated", "truncated", "returns")


def play_labelled(config, expert, learner, share: float, seeds: list[int], coin_key: list[int], client,
                  gamma: float) -> dict[str, np.ndarray]:
    """Episodes seeded `seeds` of the AllocConfig config under the mixture policy (the expert
    drives a step with probability share, else learner; learner None: the expert always), every
    state labelled with the expert's action. expert, learner: allocators (predict(obs,
    deterministic=True) -> (action, state)); coin_key: the mixture's coin flips' seed, with
    each episode's seed (so an episode's flips do not depend on the episodes played with it);
    gamma: the discount of the returns.

    Returns S visited states as arrays: obs, next_obs: (S, 2 N^2) float32; labels (the expert's
    actions), actions (the actions taken): (S, A) float32; rewards, returns (the discounted
    return from the state on): (S,) float64; terminated, truncated: (S,) bool."""
    env = SwarmAllocationEnv(config, client=client)
    rows = {k: [] for k in FIELDS}
    try:
        for seed in seeds:
            coins = np.random.default_rng([*coin_key, int(seed)])
            obs, _ = env.reset(seed=int(seed))
            rewards = []
            while True:
                label = np.asarray(expert.predict(obs, deterministic=True)[0], dtype=np.float32)
                expert_drives = coins.random() < share
                if expert_drives or learner is None:
                    action = label
                else:
                    action = np.asarray(learner.predict(obs, deterministic=True)[0], dtype=np.float32)
                next_obs, reward, terminated, truncated, _ = env.step(action)
                for key, value in (("obs", obs), ("labels", label), ("actions", action), ("rewards", reward),
                                   ("next_obs", next_obs), ("terminated", terminated), ("truncated", truncated)):
                    rows[key].append(value)
                rewards.append(reward)
                obs = next_obs
                if terminated or truncated:
                    break
            g, returns = 0.0, []
            for r in reversed(rewards):
                g = r + gamma * g
                returns.append(g)
            rows["returns"] += returns[::-1]
    finally:
        env.close()
    return _arrays(rows)


def _arrays(rows: dict) -> dict[str, np.ndarray]:
    types = {"obs": np.float32, "labels": np.float32, "actions": np.float32, "next_obs": np.float32,
             "rewards": np.float64, "returns": np.float64, "terminated": bool, "truncated": bool}
    return {k: np.asarray(rows[k], dtype=types[k]) for k in FIELDS}


def concat(parts: list[dict]) -> dict[str, np.ndarray]:
    """play_labelled's arrays of several parts, one after another."""
    return {k: np.concatenate([p[k] for p in parts]) for k in FIELDS}
