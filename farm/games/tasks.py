"""The farm's Ray task that plays a shard (farm.games.shards) on a worker. Defined once, at
import, so no remote function is built per call; imported only by code that runs on Ray.

A worker or node that dies mid-shard is Ray's to handle: the task is retried up to
MAX_RETRIES times (Ray's `ray_tasks{IsRetry!="0"}` metric shows the retries). A shard's own
exception is not retried: it would fail the same way again.
"""

from __future__ import annotations

import time

import ray

from farm.games.shards import play_outcomes, play_shard
from farm.runtime import metrics
from workers import Case

__all__ = ["MAX_RETRIES", "_remote_shard", "_remote_games"]

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
def _remote_games(jobs: list):
    """play_outcomes(case, seed, start, stop) of each job (case, seed, start, stop) on a worker,
    one after another (a coarse task of many small games); returns them, in order."""
    return [play_outcomes(case, seed, start, stop) for case, seed, start, stop in jobs]
