"""The farm's Ray tasks: play a shard (farm.shards) on a worker, and evaluate one (scenario,
policy) of a benchmark suite (farm.alloc.suite). Defined once, at import, so no remote
function is built per call; imported only by code that runs on Ray.

A worker or node that dies mid-shard is Ray's to handle: the task is retried up to
MAX_RETRIES times (Ray's `ray_tasks{IsRetry!="0"}` metric shows the retries). A shard's own
exception is not retried: it would fail the same way again.
"""

from __future__ import annotations

import time

import ray

from workers import Case

from farm import metrics
from farm.shards import play_shard

__all__ = ["MAX_RETRIES", "_remote_shard", "_remote_suite_cell"]

MAX_RETRIES = 3


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
def _remote_shard(case: Case, seed, start: int, stop: int, detail: bool = False, sweep: str | None = None):
    """play_shard(case, seed, start, stop, detail=detail) on a worker; returns (rows, the id of
    the node that ran it). sweep: the sweep's name, to record the worker-side metrics under
    (needs detail, for the game-steps)."""
    t0 = time.perf_counter()
    df = play_shard(case, seed, start, stop, detail=detail)
    if sweep is not None:
        metrics.record_shard(sweep, stop - start, int(df["steps"].sum()), time.perf_counter() - t0)
    return df, ray.get_runtime_context().get_node_id()


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
def _remote_suite_cell(config, spec, service, episodes: int, seed: int) -> list[dict]:
    """farm.alloc.suite.evaluate_cell on a worker, its client built on the shared capture-time
    service actor `service` (a handle): config: the scenario's AllocConfig; spec: the policy
    (farm.alloc.suite.build_policy); returns one dict per episode. While the client waits
    for the actor (ray.get), Ray lends this task's CPU to the service's game tasks."""
    from farm.alloc.suite import evaluate_cell
    from farm.service.lookup import CaptureTimeClient

    client = CaptureTimeClient(config.service_settings(), service=service)
    return evaluate_cell(config, spec, client, episodes, seed)
