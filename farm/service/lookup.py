"""How a game's statistics are looked up: the whole path, in this one file.

A caller (the allocation env, training's warm-up, `farm table`, the evaluators) holds a
CaptureTimeClient and asks it for the statistics of (n_pursuers, n_evaders) games under the
client's ServiceSettings. The lookup then goes, in order:

1. CaptureTimeClient: its memo of exact answers, keyed by team sizes (a dict lookup, no Ray
   round trip). What it misses goes, as one batch of StatsKeys, to its backend.
2. The backend (StatsBackend): a Lookup in this process (`local`), or the named Ray actor
   `CaptureTimeService` whose body is ServiceLookup below (`ray`; farm/service/actor.py
   only deploys it), reached through RayBackend.
3. Lookup.get_many, the one core: its memo (digest -> value), then the store
   (farm/service/store.py, SQLite), then, if asked for, an estimate from computed
   neighbours (NeighbourIndex, estimate), then compute: the key's games cut into shards
   (farm/shards.py), in this process (compute_in_process) or as Ray tasks
   (compute_on_ray: farm/tasks.py, a bounded number in flight by farm.runtime.bounded).
   A computed value is stored and remembered. Concurrent asks for one missing key compute
   it once (single flight). An estimated key is computed in the background where the
   backend has one (the actor), else on its next exact ask.

Without a store (the games-fidelity evaluation, farm.alloc.evaluate), nothing is
remembered or estimated: every ask is computed, once per position of the batch.

open_client() decides "Ray or local" once and owns the cluster and the service for as long
as the client is in use.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Iterator, Protocol, runtime_checkable

import numpy as np
import pandas as pd

from workers import CaptureStats

from farm.errors import ConfigError
from farm.service.keys import ServiceSettings, StatsKey, lattice_anchors
from farm.service.store import StatsStore
from farm.shards import games_per_shard, play_shard, shard_ranges

__all__ = ["StatsBackend", "Lookup", "LocalBackend", "ServiceLookup", "RayBackend", "CaptureTimeClient",
           "open_client", "compute_in_process", "compute_on_ray", "stats_from_games", "NeighbourIndex", "estimate",
           "ESTIMATE_NEIGHBOURS"]

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
    """Every shard of every key as a Ray task (farm.tasks), at most max_in_flight pending
    (slots: shared with other threads computing at once); a key is yielded when its last
    shard is in. Needs a running Ray."""
    import ray

    from farm.runtime import bounded
    from farm.tasks import _remote_shard

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

    def close(self) -> None:
        """Close the store's connection."""
        if self.store is not None:
            self.store.close()


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

        from farm.metrics import ServiceMetrics

        cpus = int(ray.cluster_resources().get("CPU", 1))
        limit = max_shards_in_flight or max(1, 2 * cpus)
        slots = threading.BoundedSemaphore(limit)

        def compute(keys):
            return compute_on_ray(keys, max_in_flight=limit, slots=slots)

        metrics = ServiceMetrics()
        super().__init__(StatsStore(store_path), compute, background=ThreadPoolExecutor(16), metrics=metrics)
        metrics.inflight(0)


class RayBackend:
    """The client's side of the capture-time service actor: one Ray call per batch."""

    repeatable = True

    def __init__(self, actor):
        """actor: a CaptureTimeService handle (farm.service.actor.get_service)."""
        self.actor = actor

    def get_many(self, keys: list[StatsKey], estimate: bool = False) -> list[CaptureStats]:
        """The actor's answers for keys, in order."""
        import ray

        return ray.get(self.actor.get_many.remote(keys, estimate))

    def warm(self, keys: list[StatsKey], progress: Callable[[int], None] | None = None) -> None:
        """Every key asked at once (the actor computes them in parallel on the farm)."""
        import ray

        pending = [self.actor.get_many.remote([key]) for key in keys]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            ray.get(ready)
            if progress:
                progress(len(ready))

    def stats(self) -> dict:
        """The actor's counts (Lookup.stats)."""
        import ray

        return ray.get(self.actor.stats.remote())

    def close(self) -> None:
        """Nothing: the actor outlives its clients."""


# ----------------------------------------------------------------------------- the client
class CaptureTimeClient:
    """Statistics of (n_pursuers, n_evaders) games under fixed settings: the only thing callers touch.

    settings: the ServiceSettings (default ServiceSettings()); give exactly one of
    backend (a StatsBackend), service (a CaptureTimeService actor handle) or local_store (a
    path, for an in-process LocalBackend, which the client then owns and closes).
    """

    def __init__(self, settings: ServiceSettings | None = None, *, backend: StatsBackend | None = None,
                 service=None, local_store=None):
        if sum(x is not None for x in (backend, service, local_store)) != 1:
            raise ValueError("CaptureTimeClient: give exactly one of backend=, service= or local_store=")
        self.settings = settings or ServiceSettings()
        self.owns_backend = local_store is not None
        if service is not None:
            backend = RayBackend(service)
        elif local_store is not None:
            backend = LocalBackend(local_store)
        self.backend: StatsBackend = backend
        self._memo: dict[tuple[int, int], CaptureStats] = {}
        self._estimates: dict[tuple[int, int], CaptureStats] = {}  # estimate="lattice": fixed per client

    def with_settings(self, settings: ServiceSettings) -> "CaptureTimeClient":
        """A client of other settings on the same backend (which this client keeps owning)."""
        return CaptureTimeClient(settings, backend=self.backend)

    def key(self, n_pursuers: int, n_evaders: int) -> StatsKey:
        """The StatsKey of a team-size pair under the client's settings."""
        return self.settings.key(n_pursuers, n_evaders)

    def get(self, n_pursuers: int, n_evaders: int) -> CaptureStats:
        """The statistics of one team-size pair (exact)."""
        if n_pursuers.__class__ is not bool and n_evaders.__class__ is not bool:  # True == 1 as a dict key
            value = self._memo.get((n_pursuers, n_evaders))
            if value is not None:
                return value
        return self.get_many([(n_pursuers, n_evaders)])[0]

    def get_many(self, pairs: Iterable[tuple[int, int]], *, estimate: bool | str = False) -> list[CaptureStats]:
        """One call for a batch (all engaged cells of a step): hits from the memo, the rest in
        one backend call.

        estimate: False, exact values only. True: a missing key may come back as the
        service's interpolation of whatever it has computed by then (its `estimate` says
        how) while the exact value is computed (in the background on Ray; in process, on its
        next exact ask); estimates are not memoized; which visits are estimated, and from
        what, depends on timing. "lattice": the timing-independent rule (lattice_estimates).
        """
        if estimate == "lattice":
            return self.lattice_estimates(pairs)
        if estimate not in (False, True):
            raise ConfigError(f"estimate: must be false, true or 'lattice', got {estimate!r}")
        pairs = [tuple(p) for p in pairs]
        memo = self._memo if self.backend.repeatable else {}
        out: list = [None if any(x.__class__ is bool for x in p) else memo.get(p) for p in pairs]
        missing = [i for i, v in enumerate(out) if v is None]
        if missing:
            values = self.backend.get_many([self.key(*pairs[i]) for i in missing], estimate)
            for i, value in zip(missing, values):
                out[i] = value
                if value.estimate is None and self.backend.repeatable:
                    self._memo[pairs[i]] = value
        return out

    def lattice_estimates(self, pairs: Iterable[tuple[int, int]]) -> list[CaptureStats]:
        """Statistics under the timing-independent estimate rule (`estimates: lattice`).

        A pair on the lattice (both sizes in farm.service.keys.LATTICE) is answered exactly. Any
        other pair is answered by `estimate` over its lattice anchors (lattice_anchors: the
        corners of the lattice cell holding it), which are computed exactly first, and keeps
        that answer for the client's life, whatever the service computes meanwhile; its exact
        value is asked for in the background (the service's estimate path), for evaluations and
        later runs. So whether a visit is estimated, and its value, depend only on the pair:
        a run that takes estimates is reproducible, on a cold or a warm store, alone or beside
        other runs on one service.
        """
        pairs = [tuple(p) for p in pairs]
        anchors = {p: lattice_anchors(*p) for p in pairs}
        exact = sorted({a for p in pairs for a in anchors[p]})
        values = dict(zip(exact, self.get_many(exact)))
        out, fresh = [], []
        for p in pairs:
            if anchors[p] == [p]:
                out.append(values[p])
                continue
            value = self._estimates.get(p)
            if value is None:
                value = estimate(self.key(*p), [(a[0], a[1], values[a]) for a in anchors[p]])
                self._estimates[p] = value
                fresh.append(p)
            out.append(value)
        if fresh:  # exact values for later: the service answers its own estimate and computes them
            self.backend.get_many([self.key(*p) for p in fresh], True)
        return out

    def warm(self, pairs: Iterable[tuple[int, int]], progress: Callable[[int], None] | None = None) -> int:
        """Have every pair computed (in parallel on Ray), then memoized; progress(n) as pairs
        are done. Returns the number of pairs."""
        pairs = [tuple(p) for p in pairs]
        self.backend.warm([self.key(*p) for p in pairs], progress)
        self.get_many(pairs)
        return len(pairs)

    def stats(self) -> dict:
        """The backend's counts (Lookup.stats)."""
        return self.backend.stats()

    def close(self) -> None:
        """Release the backend if this client made it (an in-process store's connection)."""
        if self.owns_backend:
            self.backend.close()


@contextmanager
def open_client(settings: ServiceSettings, *, mode: str = "ray", store, address: str | None = None,
                num_cpus: int | None = None) -> Iterator[CaptureTimeClient]:
    """A client for the duration of the block; the one place that decides "Ray or local".

    mode "ray": joins the cluster at address (or starts a local Ray, farm.runtime.ray_cluster)
    and uses the named service actor of `store` on it, which must serve that store;
    mode "local": an in-process lookup over `store`. The cluster and the in-process store
    are released at the block's end. A store no service can use (a folder, read-only,
    damaged) is refused in one line before any work (before Ray starts, when it is local).
    """
    if mode == "local":
        client = CaptureTimeClient(settings, local_store=store)
        try:
            yield client
        finally:
            client.close()
        return
    if mode != "ray":
        raise ConfigError(f"service.mode: must be 'ray' or 'local', got {mode!r}")
    import os

    from farm.runtime import connected, ray_cluster
    from farm.service.store import check_store

    if address is None and not os.environ.get("RAY_ADDRESS") and not connected():
        check_store(store)  # a new Ray on this machine, its store here: a folder, read-only or damaged, before Ray
    with ray_cluster(address, num_cpus=num_cpus):
        from farm.service.actor import get_service

        yield CaptureTimeClient(settings, service=get_service(Path(store)))
