"""The capture-time service as a named async Ray actor: an in-memory cache over
the SQLite store, misses computed on the farm (each shard a Ray task, a bounded
number in flight), single-flight (concurrent asks for one missing key compute
it once), batch queries, optional estimates for keys not computed yet."""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from pathlib import Path

import pandas as pd
import ray

from workers import CaptureStats

from farm.runtime import NAMESPACE
from farm.service.core import NeighbourIndex, compute_shard, estimate, shard_ranges, stats_from_games
from farm.service.keys import StatsKey
from farm.service.store import StatsStore

SERVICE_NAME = "capture-time-service"
log = logging.getLogger(__name__)


@ray.remote(num_cpus=1, max_retries=3, retry_exceptions=False)
def _shard_task(key: StatsKey, start: int, stop: int) -> pd.DataFrame:
    return compute_shard(key, start, stop)


@ray.remote(num_cpus=0, max_restarts=3)
class CaptureTimeService:
    def __init__(self, store_path: str, max_shards_in_flight: int | None = None):
        from farm import metrics

        self.store = StatsStore(store_path)
        self.cache: dict[str, CaptureStats] = self.store.load_all()
        self.index = NeighbourIndex(self.store, self.cache)
        self.inflight: dict[str, asyncio.Future] = {}
        self.tasks: set = set()
        self.computations: Counter = Counter()
        self.counts: Counter = Counter()
        self.compute_seconds = 0.0
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.slots = asyncio.Semaphore(max_shards_in_flight or max(1, 2 * cpus))
        self.metrics = metrics.ServiceMetrics()
        self.metrics.inflight(0)

    async def get_many(self, keys: list[StatsKey], estimate_missing: bool = False) -> list[CaptureStats]:
        out: list = [None] * len(keys)
        waits = []
        for i, key in enumerate(keys):
            d = key.digest()
            value = self.cache.get(d) or self._from_store(key, d)
            if value is not None:
                out[i] = value
                self.counts["hits"] += 1
                self.metrics.hit()
                continue
            self.counts["misses"] += 1
            self.metrics.miss()
            future = self.inflight.get(d) or self._start(key, d)
            if estimate_missing:
                guess = estimate(key, self.index.neighbours(key))
                if guess is not None:
                    out[i] = guess
                    continue
            waits.append((i, future))
        for i, future in waits:
            out[i] = await asyncio.shield(future)
        return out

    def _from_store(self, key: StatsKey, digest: str) -> CaptureStats | None:
        """A key another process stored since this actor started."""
        value = self.store.get(key)
        if value is not None:
            self.cache[digest] = value
            self.index.add(key, value)
        return value

    def _start(self, key: StatsKey, digest: str) -> asyncio.Future:
        future = asyncio.get_running_loop().create_future()
        future.add_done_callback(lambda f: f.cancelled() or f.exception())  # retrieved even if nobody waits
        self.inflight[digest] = future
        self.metrics.inflight(len(self.inflight))
        task = asyncio.ensure_future(self._compute(key, digest, future))
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)
        return future

    async def _shard(self, key: StatsKey, start: int, stop: int) -> pd.DataFrame:
        async with self.slots:
            return await _shard_task.remote(key, start, stop)

    async def _compute(self, key: StatsKey, digest: str, future: asyncio.Future) -> None:
        t0 = time.perf_counter()
        try:
            frames = await asyncio.gather(*(self._shard(key, a, b) for a, b in shard_ranges(key)))
            value = stats_from_games(pd.concat(frames, ignore_index=True))
            self.store.put(key, value)
            self.cache[digest] = value
            self.index.add(key, value)
            self.computations[digest] += 1
            future.set_result(value)
        except BaseException as e:  # handed to every waiter, cancellation included
            log.exception("computing %s failed", digest)
            if not future.done():
                future.set_exception(e if isinstance(e, Exception) else RuntimeError(f"cancelled: {e!r}"))
            if not isinstance(e, Exception):
                raise
        finally:
            seconds = time.perf_counter() - t0
            self.compute_seconds += seconds
            self.inflight.pop(digest, None)
            self.metrics.computed(seconds)
            self.metrics.inflight(len(self.inflight))

    def stats(self) -> dict:
        return {**self.counts, "computations": dict(self.computations), "inflight": len(self.inflight),
                "stored": len(self.cache), "compute_seconds": self.compute_seconds,
                "corrupt_rows": list(self.store.corrupt_rows), "store": str(self.store.path)}


def get_service(store_path, *, name: str = SERVICE_NAME, detached: bool = False, max_shards_in_flight=None):
    """Find the named service in the project's namespace, or create it (needs ray.init).

    The actor is kept on the head node, where its store lives.
    """
    options = dict(name=name, namespace=NAMESPACE, get_if_exists=True, max_concurrency=1000)
    if detached:
        options["lifetime"] = "detached"
    if "node:__internal_head__" in ray.cluster_resources():
        options["resources"] = {"node:__internal_head__": 0.001}
    return CaptureTimeService.options(**options).remote(str(Path(store_path).resolve()), max_shards_in_flight)
