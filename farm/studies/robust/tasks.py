"""The meta-game's Ray tasks: one (allocator, intruder policy) pair's episodes (play_pair on a
worker), one allocator's exact searches (remote_exact). Imports Ray: imported only by
farm.studies.robust.payoffs.fill and farm.studies.robust.exact.fill_exact once Ray is up."""

from __future__ import annotations

import ray

from farm.games.tasks import MAX_RETRIES
from farm.studies.robust.members import play_pair

__all__ = ["remote_pair", "remote_exact"]


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
def remote_pair(config, allocator, intruders, service, episodes: int, seed: int) -> dict:
    """play_pair on a worker, its client on the shared capture-time service actor `service`; one torch thread."""
    import torch

    from farm.service.client import CaptureTimeClient

    torch.set_num_threads(1)
    client = CaptureTimeClient(config.game_settings(), service=service)
    return play_pair(config, allocator, intruders, client, episodes, seed)


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
def remote_exact(config, allocator, service, episodes: int, seed: int, objective: str) -> dict:
    """The intruders' exact best response (minimising objective) against allocator (a Member) on
    episodes seeded seed .. seed + episodes - 1 of config: {measure: list of floats, one an
    episode}, as remote_pair's."""
    import torch

    from farm.alloc.allocators import make_allocator
    from farm.alloc.intruders.exact_search import exact_response
    from farm.service.client import CaptureTimeClient
    from farm.studies.robust.members import MEASURES

    torch.set_num_threads(1)
    client = CaptureTimeClient(config.game_settings(), service=service)
    policy = make_allocator(allocator.name, config, client, **allocator.options)
    found = [exact_response(config, policy, client, seed + k, objective=objective).summary
             for k in range(episodes)]
    return {m: [s[m] for s in found] for m in MEASURES}
