"""The suite's Ray task: episodes of one (scenario, allocator) matchup (evaluate_matchup on a
worker; farm.studies.suite.run.matchup_tasks cuts a matchup's episodes into tasks). Imports Ray:
imported only by farm.studies.suite.run.run_suite, once Ray is up
(farm.runtime.ray_cluster sets Ray's loopback switch before Ray's import)."""

from __future__ import annotations

import ray

from farm.games.tasks import MAX_RETRIES
from farm.studies.suite.matchup import evaluate_matchup

__all__ = ["remote_suite_matchup"]


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
def remote_suite_matchup(config, spec, service, episodes: int, seed: int) -> list[dict]:
    """evaluate_matchup on a worker, its client built on the shared capture-time service actor
    `service` (a handle): config: the scenario's AllocConfig; spec: the allocator (a
    farm.alloc.allocators.Spec); the episodes seeded seed .. seed + episodes - 1; returns
    one dict per episode, numbered from 0. While the client waits for the actor (ray.get), Ray
    lends this task's CPU to the service's game tasks."""
    from farm.service.client import CaptureTimeClient

    client = CaptureTimeClient(config.game_settings(), service=service)
    return evaluate_matchup(config, spec, client, episodes, seed)
