"""How a game's statistics are looked up: the whole path, in this one file.

A caller (the allocation env, training's warm-up, `farm table`, the evaluators) holds a
CaptureTimeClient and asks it for the statistics of (n_pursuers, n_evaders) games under the
client's GameSettings. The lookup then goes, in order:

1. CaptureTimeClient (farm/service/client.py, with RayBackend and open_client): its memo of
   exact answers, keyed by team sizes; what it misses goes, as one batch of StatsKeys, to:
2. the backend (StatsBackend): a Lookup in this process (`local`), or the named Ray actor
   `CaptureTimeService` whose body is ServiceLookup below (`ray`; farm/service/actor.py);
3. Lookup.get_many, the one core: its memo, then the store (farm/service/store.py), then, if
   asked for, an estimate from computed neighbours (NeighbourIndex, estimate), then compute:
   the key's games cut into shards (farm/games/shards.py), here or as Ray tasks
   (compute_in_process, compute_on_ray). Lookup's docstring says the rest.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from typing import Protocol, runtime_checkable

import numpy as np
import pandas as pd

from farm.games.shards import games_per_shard, play_shard, shard_ranges
from farm.service.keys import StatsKey
from farm.service.store import StatsStore
from workers import CaptureStats

__all__ = ["StatsBackend", "Lookup", "LocalBackend", "ServiceLookup", "compute_in_process", "compute_on_ray",
           "stats_from_games", "NeighbourIndex", "estimate", "ESTIMATE_NEIGHBOURS"]

log = logging.getLogger(__name__)

ESTIMATE_NEIGHBOURS = 4

# compute(keys) yields (position in keys, value) as each key's games are done.
Compute = Callable[[list[StatsKey]], Iterator[tuple[int, CaptureStats]]]


@runtime_checkable
class StatsBackend(Protocol):
    """What a CaptureTimeClient asks: statistics of these keys."""

    repeatable: bool  # the same key always gets the same value (so the client may memoize it)

    def get_many(self, keys: list[StatsKey], estimate: bool = False) -> list[CaptureStats]:
        """One value per key, in order; with estimate, a missing key may come back as an estimate."""

    def warm(self, keys: list[StatsKey], progress: Callable[[int], None] | None = None) -> None:
        """Have every key computed (in parallel where the backend can), calling progress(1) per key done."""

    def stats(self) -> dict:
        """Counts: hits, misses, asked, computations {digest: n}, inflight, stored, compute_seconds, corrupt_rows,
        store."""

    def close(self) -> None:
        """Release what the backend holds (the store's connection, for an in-process one)."""


# ----------------------------------------------------------------------------- computing
def stats_from_games(per_game: pd.DataFrame) -> CaptureStats:
    """The service's value (docs/model.md section 4) of a key's per-game rows, in any order."""
    return CaptureStats.from_games(per_game.sort_values("game", kind="stable"))


def _ranges(key: StatsKey) -> list[tuple[int, int]]:
    return shard_ranges(key.games, games_per_shard(key.case))


def compute_in_process(keys: list[StatsKey]) -> Iterator[tuple[int, CaptureStats]]:
    """Each key's games, shard by shard, in this process (game g is default_rng([seed, g]))."""
    for k, key in enumerate(keys):
        frames = [play_shard(key.case, key.seed, a, b) for a, b in _ranges(key)]
        yield k, stats_from_games(pd.concat(frames, ignore_index=True))


def compute_on_ray(keys: list[StatsKey], *, max_in_flight: int,
                   slots: threading.Semaphore | None = None) -> Iterator[tuple[int, CaptureStats]]:
    """Every shard of every key as a Ray task (farm.games.tasks), at most max_in_flight pending
    (slots: shared with other threads computing at once); a key is yielded when its last
    shard is in. Needs a running Ray."""
    import ray

    from farm.games.tasks import _remote_shard
    from farm.runtime import bounded

    jobs = [(k, a, b) for k, key in enumerate(keys) for a, b in _ranges(key)]
    left = Counter(k for k, _, _ in jobs)
    frames: dict[int, list[pd.DataFrame]] = {}

    def submit(job):
        k, a, b = job
        return _remote_shard.remote(keys[k].case, keys[k].seed, a, b)

    for (k, _, _), ref in bounded(submit, jobs, max_in_flight, slots=slots):
        frames.setdefault(k, []).append(ray.get(ref)[0])
        left[k] -= 1
        if left[k] == 0:
            yield k, stats_from_games(pd.concat(frames.pop(k), ignore_index=True))


# ----------------------------------------------------------------------------- estimating
class NeighbourIndex:
    """The computed cases of each setting by team sizes, in memory, for estimates: reading
    them from the store on every miss would parse and verify every row of the setting."""

    def __init__(self, rows: list[tuple[str, str, int, int, CaptureStats]]):
        """rows: the store's verified rows (StatsStore.rows(): a row whose checksum does not
        cover its settings and team sizes, or whose columns disagree with its key, is left out)."""
        self._by_settings: dict[str, dict[tuple[int, int], CaptureStats]] = {}
        for _, settings, n_p, n_e, value in rows:
            self._by_settings.setdefault(settings, {})[(n_p, n_e)] = value

    def add(self, key: StatsKey, value: CaptureStats) -> None:
        """Remember a computed key's value."""
        self._by_settings.setdefault(key.settings_digest(), {})[key.sizes] = value

    def neighbours(self, key: StatsKey) -> list[tuple[int, int, CaptureStats]]:
        """Computed cases with the same settings as key: (n_p, n_e, value)."""
        return [(n_p, n_e, v) for (n_p, n_e), v in self._by_settings.get(key.settings_digest(), {}).items()]


def estimate(key: StatsKey, neighbours: list[tuple[int, int, CaptureStats]]) -> CaptureStats | None:
    """Inverse-distance (power 2) average of every statistic over the nearest stored
    (n_p, n_e) of the same settings (n_games 0, `estimate` saying how); None without neighbours.

    Neighbours at distance 0 (the key's own team sizes) are the estimate: their plain mean
    (one such neighbour: its statistics), never 0/0. Duplicate sizes weigh alike."""
    if not neighbours:
        return None
    n_p, n_e = key.sizes
    sizes = np.array([(a, b) for a, b, _ in neighbours], dtype=np.float64)
    d = np.hypot(sizes[:, 0] - n_p, sizes[:, 1] - n_e)
    nearest = np.argsort(d, kind="stable")[:ESTIMATE_NEIGHBOURS]
    own = bool(d[nearest[0]] == 0)
    if own:  # the key's own sizes: no distance to weigh by (1 / 0**2 would make every statistic 0/0)
        nearest = nearest[d[nearest] == 0]
        w = np.ones(len(nearest))
    else:
        w = 1.0 / d[nearest] ** 2
    w /= w.sum()
    rows = [neighbours[i][2].flat() for i in nearest]
    out: dict = {}
    for name in rows[0]:
        xs = np.array([float(r[name]) for r in rows])
        ok = np.isfinite(xs)
        out[name] = float(np.sum(w[ok] * xs[ok]) / np.sum(w[ok])) if ok.any() else math.nan
    out["n_games"] = 0
    used = ", ".join(f"({neighbours[i][0]},{neighbours[i][1]})" for i in nearest)
    how = "mean of the cases of its own team sizes" if own else "inverse-distance (power 2)"
    return CaptureStats.from_flat(out, estimate=f"{how} over the {len(nearest)} nearest stored (n_p, n_e): {used}")


# ----------------------------------------------------------------------------- the core
class Lookup:
    """memo, then store, then estimate, then compute; thread-safe, single flight.

    A computed value is stored and remembered. Concurrent asks for one missing key compute it
    once (single flight). An estimated key is computed in the background where the backend has
    one (the actor), else on its next exact ask. Without a store (the games-fidelity
    evaluation, farm.alloc.evaluation.rollout) nothing is remembered or estimated. compute_on_ray keeps a
    bounded number of tasks in flight (farm.runtime.bounded); open_client() (client.py) decides
    "Ray or local" once and owns the cluster and the service while the client is in use.

    store: a StatsStore (values are remembered, stored and estimated from), or None (every
    ask is computed, once per position: nothing is remembered). compute: how missing keys
    are computed (compute_in_process, compute_on_ray). background: where an estimated key
    is computed while its estimate is answered; None: it is computed on its next exact ask.
    metrics: an object with hit(), miss(), computed(seconds), inflight(n) (the actor's Ray
    metrics), or None.
    """

    def __init__(self, store: StatsStore | None, compute: Compute, *, background: Executor | None = None,
                 metrics=None):
        self.store = store
        self.compute = compute
        self.background = background
        self.metrics = metrics
        rows = store.rows() if store is not None else []  # each row read and verified once
        self.cache: dict[str, CaptureStats] = {digest: value for digest, _, _, _, value in rows}
        self.index = NeighbourIndex(rows) if store is not None else None
        self.inflight: dict[str, Future] = {}
        self.counts: Counter = Counter(hits=0, misses=0)
        self.asked: set[str] = set()  # the digests of every key asked (stats' `asked` is their number)
        self.computations: Counter = Counter()
        self.compute_seconds = 0.0
        self._lock = threading.Lock()

    def get_many(self, keys: list[StatsKey], estimate: bool = False) -> list[CaptureStats]:
        """One value per key, in order (see the module doc for the path)."""
        out: list = [None] * len(keys)
        mine: list[tuple[int, StatsKey, Future]] = []  # to compute here
        theirs: list[tuple[int, Future]] = []  # computed by another ask
        behind: list[tuple[int, StatsKey, Future]] = []  # estimated now, computed in the background
        with self._lock:
            for i, key in enumerate(keys):
                if self.store is None:
                    mine.append((i, key, Future()))
                    continue
                digest = key.digest()
                self.asked.add(digest)
                value = self.cache.get(digest) or self._from_store(key, digest)
                if value is not None:
                    out[i] = value
                    self._count("hits")
                    continue
                self._count("misses")
                guess = _estimate(key, self.index.neighbours(key)) if estimate else None
                future = self.inflight.get(digest)
                if guess is not None:
                    out[i] = guess
                    if future is None and self.background is not None:
                        behind.append((i, key, self._claim(digest)))
                elif future is not None:
                    theirs.append((i, future))
                else:
                    mine.append((i, key, self._claim(digest)))
        for item in behind:
            self.background.submit(self._compute, [item])
        if mine:
            self._compute(mine)
        for i, _, future in mine:
            out[i] = future.result()
        for i, future in theirs:
            out[i] = future.result()
        return out

    def _from_store(self, key: StatsKey, digest: str) -> CaptureStats | None:
        """A key another process stored since this lookup started."""
        value = self.store.get(key)
        if value is not None:
            self.cache[digest] = value
            self.index.add(key, value)
        return value

    def _claim(self, digest: str) -> Future:
        future: Future = Future()
        self.inflight[digest] = future
        if self.metrics:
            self.metrics.inflight(len(self.inflight))
        return future

    def _count(self, what: str) -> None:
        self.counts[what] += 1
        if self.metrics:
            (self.metrics.hit if what == "hits" else self.metrics.miss)()

    def _compute(self, batch: list[tuple[int, StatsKey, Future]]) -> None:
        """Compute a batch's keys, store and remember each as it is done, resolve its futures;
        a failure is handed to every waiter still waiting (and so to the caller)."""
        t0 = time.perf_counter()
        keys = [key for _, key, _ in batch]
        error: Exception | None = None
        try:
            for k, value in self.compute(keys):
                _, key, future = batch[k]
                if self.store is not None:
                    self._record(key, value, time.perf_counter() - t0)
                future.set_result(value)
        except Exception as e:  # whatever the games or Ray raised: each waiter gets it
            log.exception("computing %d case(s) failed", len(keys))
            error = e
        finally:  # also when interrupted: nobody waits for ever
            for _, key, future in batch:
                if not future.done():
                    future.set_exception(error or RuntimeError("the computation was interrupted"))
                    self._release(key)

    def _record(self, key: StatsKey, value: CaptureStats, seconds: float) -> None:
        digest = key.digest()
        self.store.put(key, value)
        with self._lock:
            self.cache[digest] = value
            self.index.add(key, value)
            self.computations[digest] += 1
            self.compute_seconds += seconds
        self._release(key)
        if self.metrics:
            self.metrics.computed(seconds)

    def _release(self, key: StatsKey) -> None:
        with self._lock:
            self.inflight.pop(key.digest(), None)
            if self.metrics:
                self.metrics.inflight(len(self.inflight))

    def stats(self) -> dict:
        """hits, misses, asked (the distinct keys ever asked), computations {digest: times
        computed}, inflight, stored, compute_seconds, corrupt_rows and the store's path (a
        lookup without a store counts none of them). From a cold store, every key asked was
        computed exactly once when computations holds `asked` digests, each counted once."""
        with self._lock:
            return {**self.counts, "asked": len(self.asked), "computations": dict(self.computations),
                    "inflight": len(self.inflight), "stored": len(self.cache), "compute_seconds": self.compute_seconds,
                    "corrupt_rows": sorted(self.store.corrupt_rows) if self.store is not None else [],
                    "store": str(self.store.path) if self.store is not None else None}

    def store_path(self) -> str | None:
        """The store's resolved path (None without a store)."""
        return str(self.store.path) if self.store is not None else None

    closed = False  # set by close(): a closed lookup answers nothing more

    def close(self) -> None:
        """Close the store's connection; the lookup is closed (`closed`)."""
        if self.store is not None:
            self.store.close()
        self.closed = True


_estimate = estimate  # Lookup.get_many's `estimate` flag shadows the function's name there


# ----------------------------------------------------------------------------- the backends
class LocalBackend(Lookup):
    """The lookup in this process, no Ray (unit tests, small scripts, `service.mode: local`):
    misses are computed here; an estimated key is computed on its next exact ask."""

    repeatable = True

    def __init__(self, store_path):
        """store_path: the SQLite store (created if missing)."""
        super().__init__(StatsStore(store_path), compute_in_process)

    def warm(self, keys: list[StatsKey], progress: Callable[[int], None] | None = None) -> None:
        """Compute every key, one after another."""
        for key in keys:
            self.get_many([key])
            if progress:
                progress(1)


class ServiceLookup(Lookup):
    """The body of the capture-time service actor (farm.service.actor deploys it): a Lookup
    over the store whose misses are Ray tasks, at most max_shards_in_flight pending over
    all asks (default twice the cluster's CPUs), estimated keys computed in the background,
    counts exported as Ray metrics."""

    def __init__(self, store_path: str, max_shards_in_flight: int | None = None):
        """store_path: the SQLite store on the node the actor runs on."""
        import ray

        from farm.runtime.metrics import ServiceMetrics

        cpus = int(ray.cluster_resources().get("CPU", 1))
        limit = max_shards_in_flight or max(1, 2 * cpus)
        slots = threading.BoundedSemaphore(limit)

        def compute(keys):
            return compute_on_ray(keys, max_in_flight=limit, slots=slots)

        metrics = ServiceMetrics()
        super().__init__(StatsStore(store_path), compute, background=ThreadPoolExecutor(16), metrics=metrics)
        metrics.inflight(0)
