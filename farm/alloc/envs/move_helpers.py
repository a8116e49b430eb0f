"""A frozen allocator's moves for a batch of episodes spread over helper processes (Ray actors on
the caller's node), for an intruders' env whose allocator plans (a planner's move costs
milliseconds, the intruders' network's microseconds): the episodes are independent, so each
helper answers a slice of the batch with its own copy of the allocator.

What an episode's allocator draws (a mixture's member, farm.alloc.allocators.mixture) is drawn
where the episode runs, from the episode's generator (`chosen`); the helpers only answer the
drawn member's deterministic move. So the moves, and every number after them, are the same
whatever the number of helpers.
"""

from __future__ import annotations

import numpy as np

from farm.core.errors import ConfigError

__all__ = ["MoveHelpers", "chosen", "check_procs"]


def check_procs(procs) -> int:
    """procs as an int >= 1 (the processes that answer the allocator's moves: the env's own and
    procs - 1 helpers), else a one-line ConfigError naming `opponent_procs`."""
    from farm.core.checks import is_whole

    if not is_whole(procs) or procs < 1:
        raise ConfigError(f"opponent_procs: must be a whole number >= 1, got {procs!r}", field="opponent_procs")
    return int(procs)


def chosen(player, policy) -> tuple:
    """What an episode's player (for_episode's result) plays this step, drawn now from the
    episode's generator as its predict() would draw it: () the allocator `policy` itself, (k,)
    its member k (a mixture's), or None for a player that is neither (asked where the episode
    runs)."""
    if player is policy:
        return None if _draws_itself(policy) else ()
    choose = getattr(player, "choose", None)
    if choose is None or getattr(player, "mixture", None) is not policy:
        return None
    k = choose()
    return None if _draws_itself(policy.players[k]) else (k,)


def _draws_itself(policy) -> bool:
    """Whether policy's predict() draws from a generator of its own (a mixture drawing per call)."""
    return getattr(policy, "draw", "mean") != "mean" and hasattr(policy, "players")


def played(policy, path: tuple):
    """The allocator a path of `chosen` names: policy itself or its member."""
    return policy if path == () else policy.players[path[0]]


class _Helper:
    """One helper: its own copy of the allocator, on the capture-time service actor `service`."""

    def __init__(self, config, name: str, options: dict, service):
        import torch

        from farm.alloc.game.registry import ALLOCATORS
        from farm.service.client import CaptureTimeClient

        torch.set_num_threads(1)
        self.policy = ALLOCATORS.make(name, config, CaptureTimeClient(config.game_settings(), service=service),
                                  **options)

    def predict(self, paths: list, obs: np.ndarray) -> list:
        """Each observation's action (as the allocator gives it) by the allocator its path names;
        obs: (m, 2 N^2) float32."""
        return [played(self.policy, p).predict(o, deterministic=True)[0] for p, o in zip(paths, obs)]


class MoveHelpers:
    """procs - 1 helper actors on this node (at most its CPUs - 1; num_cpus 0: they share the CPUs
    of the process that made them, as its threads would), each holding the allocator `name` with
    options; moves(policy, players, obs) answers a batch with the helpers and the caller together.
    Needs a running Ray and a client on the capture-time service actor (ConfigError naming
    `opponent_procs` otherwise)."""

    def __init__(self, config, client, name: str, options: dict, procs: int):
        import ray
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        actor = getattr(getattr(client, "backend", None), "actor", None)
        if not ray.is_initialized() or actor is None:
            raise ConfigError("opponent_procs: helpers need Ray and the capture-time service on it (a farm "
                              "experiment's trial); use 1 here", field="opponent_procs")
        node = ray.get_runtime_context().get_node_id()
        cpus = next((n["Resources"].get("CPU", 1) for n in ray.nodes() if n["NodeID"] == node), 1)
        here = NodeAffinitySchedulingStrategy(node, soft=False)
        remote = ray.remote(num_cpus=0, scheduling_strategy=here)(_Helper)
        self.actors = [remote.remote(config, name, options, actor) for _ in range(min(procs, int(cpus)) - 1)]

    def moves(self, policy, players: list, obs: np.ndarray) -> list:
        """Each episode's action: players (B,) the episodes' allocators, obs (B, 2 N^2) float32 ->
        B actions; the batch split in order among the caller and the helpers."""
        import ray

        paths = [chosen(p, policy) for p in players]
        here = [k for k, p in enumerate(paths) if p is None]  # players that draw for themselves
        shared = [k for k, p in enumerate(paths) if p is not None]
        parts = np.array_split(np.asarray(shared, dtype=np.int64), len(self.actors) + 1)
        refs = [a.predict.remote([paths[k] for k in part], obs[part]) for a, part in zip(self.actors, parts[1:])
                if len(part)]
        actions: list = [None] * len(players)
        for k in here:
            actions[k] = players[k].predict(obs[k], deterministic=True)[0]
        for k in parts[0].tolist():
            actions[k] = played(policy, paths[k]).predict(obs[k], deterministic=True)[0]
        answered = [part for part in parts[1:] if len(part)]
        for part, values in zip(answered, ray.get(refs)):
            for k, a in zip(part.tolist(), values):
                actions[k] = a
        return actions

    def close(self) -> None:
        """Stop the helpers (closing twice does nothing more)."""
        import ray

        for a in self.actors:
            ray.kill(a)
        self.actors = []
