"""The meta-game's Ray actors: a run's players (Players: at most `workers` Player actors, each
playing one (allocator, intruder policy) pair's episodes or one allocator's exact searches at a
time). Imports Ray: imported only by the robust loop and the exploit study once Ray is up."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator

import ray

from farm.games.tasks import MAX_RETRIES
from farm.studies.robust.members import MEASURES, play_pair

__all__ = ["Player", "Players"]


@ray.remote(num_cpus=0, max_restarts=MAX_RETRIES, max_task_retries=MAX_RETRIES)
class Player:
    """Plays pairs and exact searches for one run, with one torch thread and one client a game
    setting on the shared capture-time service actor `service` each call names (the client's memo
    kept between calls). It asks Ray for no CPU, so the trials that train between its calls keep
    theirs: Players keeps at most one call a player in flight. Restarted, with its call retried,
    when its process dies."""

    def __init__(self):
        import torch

        import farm.alloc.intruders  # noqa: F401  (the registries and the rollout, loaded while the driver goes on)
        import farm.alloc.policies  # noqa: F401
        import farm.alloc.rollout  # noqa: F401

        torch.set_num_threads(1)
        self.clients: dict = {}

    def _client(self, config, service):
        from farm.service.client import CaptureTimeClient

        settings = config.game_settings()
        if settings not in self.clients:
            self.clients[settings] = CaptureTimeClient(settings, service=service)
        return self.clients[settings]

    def pair(self, config, allocator, intruders, service, episodes: int, seed: int) -> dict:
        """play_pair: {measure: list of floats, one an episode}."""
        return play_pair(config, allocator, intruders, self._client(config, service), episodes, seed)

    def exact(self, config, allocator, service, episodes: int, seed: int, objective: str) -> dict:
        """The intruders' exact best response (minimising objective) against allocator (a Member)
        on episodes seeded seed .. seed + episodes - 1 of config: {measure: list of floats, one an
        episode}, as pair's."""
        from farm.alloc.intruders.search import exact_response
        from farm.alloc.policies import make_policy

        client = self._client(config, service)
        policy = make_policy(allocator.name, config, client, **allocator.options)
        found = [exact_response(config, policy, client, seed + k, objective=objective).summary
                 for k in range(episodes)]
        return {m: [s[m] for s in found] for m in MEASURES}


class Players:
    """A run's `workers` Player actors on client's service actor, started at once (their imports
    overlap the driver's work until the first play) and kept until close(), so that each process
    loads the policies once for the whole run rather than once a task."""

    def __init__(self, client, workers: int):
        self.service = client.backend.actor
        self.workers = workers
        self.actors: list = [Player.remote() for _ in range(workers)]

    def __enter__(self) -> Players:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def map(self, call: Callable, jobs: list) -> Iterator[tuple]:
        """call(actor, service, job) (an ObjectRef; service: the capture-time service actor) for
        each job, one at a time on each player; yields (job, ref) of each finished call, in the
        order they finish (ray.get(ref) then returns at once, or raises the call's error)."""
        idle, queue, pending = list(self.actors), deque(jobs), {}
        while queue or pending:
            while queue and idle:
                actor, job = idle.pop(), queue.popleft()
                pending[call(actor, self.service, job)] = (job, actor)
            ready, _ = ray.wait(list(pending), num_returns=1)
            job, actor = pending.pop(ready[0])
            idle.append(actor)
            yield job, ready[0]

    def close(self) -> None:
        """End the players."""
        for actor in self.actors:
            ray.kill(actor)
        self.actors = []
