"""The meta-game's Ray task: one (allocator, intruder policy) pair's episodes (play_pair on a
worker). Imports Ray: imported only by farm.studies.robust.payoffs.fill once Ray is up."""

from __future__ import annotations

import ray

from farm.games.tasks import MAX_RETRIES
from farm.studies.robust.members import play_pair

__all__ = ["remote_pair"]


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
def remote_pair(config, allocator, intruders, service, episodes: int, seed: int) -> dict:
    """play_pair on a worker, its client on the shared capture-time service actor `service`; one torch thread."""
    import torch

    from farm.service.client import CaptureTimeClient

    torch.set_num_threads(1)
    client = CaptureTimeClient(config.game_settings(), service=service)
    return play_pair(config, allocator, intruders, client, episodes, seed)
