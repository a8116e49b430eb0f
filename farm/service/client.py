"""The client side of the capture-time service: CaptureTimeClient (the only thing callers
touch: its memo of exact answers, then one batch per miss to its backend), RayBackend (the
named service actor's side, farm/service/actor.py) and open_client, the one place that
decides "Ray or local". The lookup itself is farm/service/lookup.py."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from farm.core.errors import ConfigError
from farm.service.keys import GameSettings, StatsKey, lattice_anchors
from farm.service.lookup import LocalBackend, StatsBackend, estimate
from workers import CaptureStats, InputError

__all__ = ["CaptureTimeClient", "RayBackend", "open_client"]


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

    settings: the GameSettings (default GameSettings()); give exactly one of
    backend (a StatsBackend), service (a CaptureTimeService actor handle) or local_store (a
    path, for an in-process LocalBackend, which the client then owns and closes).
    """

    def __init__(self, settings: GameSettings | None = None, *, backend: StatsBackend | None = None,
                 service=None, local_store=None):
        if sum(x is not None for x in (backend, service, local_store)) != 1:
            raise ValueError("CaptureTimeClient: give exactly one of backend=, service= or local_store=")
        self.settings = settings or GameSettings()
        self.owns_backend = local_store is not None
        if service is not None:
            backend = RayBackend(service)
        elif local_store is not None:
            backend = LocalBackend(local_store)
        self.backend: StatsBackend = backend
        self._memo: dict[tuple[int, int], CaptureStats] = {}
        self._estimates: dict[tuple[int, int], CaptureStats] = {}  # estimate="lattice": fixed per client

    def with_settings(self, settings: GameSettings) -> CaptureTimeClient:
        """A client of other settings on the same backend (which this client keeps owning)."""
        return CaptureTimeClient(settings, backend=self.backend)

    @property
    def repeatable(self) -> bool:
        """Whether a pair always gets the same answer (False for the games fidelity: every ask is a game)."""
        return self.backend.repeatable

    def key(self, n_pursuers: int, n_evaders: int) -> StatsKey:
        """The StatsKey of a team-size pair under the client's settings."""
        return self.settings.key(n_pursuers, n_evaders)

    def _check_open(self) -> None:
        """InputError (one line) when the backend was closed: a closed client answers nothing."""
        if getattr(self.backend, "closed", False):
            raise InputError("CaptureTimeClient: closed (its store's connection too); open a new client to ask again")

    def get(self, n_pursuers: int, n_evaders: int) -> CaptureStats:
        """The statistics of one team-size pair (exact); InputError after close()."""
        self._check_open()
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
        InputError after close().
        """
        self._check_open()
        if estimate == "lattice":
            return self.lattice_estimates(pairs)
        if estimate not in (False, True):
            raise ConfigError(f"estimate: must be false, true or 'lattice', got {estimate!r}", field="estimate")
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
        self._check_open()
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
def open_client(settings: GameSettings, *, mode: str = "ray", store, address: str | None = None,
                num_cpus: int | None = None) -> Iterator[CaptureTimeClient]:
    """A client for the duration of the block; the one place that decides "Ray or local".

    mode "ray": joins the cluster at address (or starts a local Ray, farm.runtime.ray_cluster)
    and uses the named service actor of `store` on it, which must serve that store;
    mode "local": an in-process lookup over `store`. The cluster, the service actor if this
    block made it (farm.service.actor.service_of) and the in-process store are released at
    the block's end. A store no service can use (a folder, read-only,
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
        raise ConfigError(f"service.mode: must be 'ray' or 'local', got {mode!r}", field="service.mode")
    from farm.runtime import ray_cluster, starts_local_ray
    from farm.service.store import check_store

    if starts_local_ray(address):
        check_store(store)  # a new Ray on this machine, its store here: a folder, read-only or damaged, before Ray
    with ray_cluster(address, num_cpus=num_cpus):
        from farm.service.actor import service_of

        with service_of(Path(store)) as service:
            yield CaptureTimeClient(settings, service=service)
