"""The trainer's client: a local memo in front of the service, so a hit costs a
dict lookup and no Ray round trip; works in-process without Ray too."""

from __future__ import annotations

from workers import CaptureStats

from farm.service.keys import ServiceSettings, StatsKey


class CaptureTimeClient:
    """Statistics of (n_pursuers, n_evaders) games under fixed settings.

    service: a CaptureTimeService actor handle; or local_store: a path, for the
    in-process LocalService (no Ray).
    """

    def __init__(self, settings: ServiceSettings | None = None, *, service=None, local_store=None):
        if (service is None) == (local_store is None):
            raise ValueError("CaptureTimeClient: give exactly one of service= or local_store=")
        self.settings = settings or ServiceSettings()
        self.service = service
        self.local = None
        if local_store is not None:
            from farm.service.local import LocalService

            self.local = LocalService(local_store)
        self._memo: dict[tuple[int, int], CaptureStats] = {}

    def key(self, n_pursuers: int, n_evaders: int) -> StatsKey:
        return self.settings.key(n_pursuers, n_evaders)

    def get(self, n_pursuers: int, n_evaders: int) -> CaptureStats:
        if n_pursuers.__class__ is not bool and n_evaders.__class__ is not bool:  # True == 1 as a dict key
            value = self._memo.get((n_pursuers, n_evaders))
            if value is not None:
                return value
        return self.get_many([(n_pursuers, n_evaders)])[0]

    def get_many(self, pairs, *, estimate: bool = False) -> list[CaptureStats]:
        """One call for a batch (all engaged cells of a step): hits from the memo, the
        rest in a single service call. With estimate=True a missing key may come
        back as an interpolation (its `estimate` says how) while the exact value
        is computed in the background; estimates are not memoized."""
        pairs = [tuple(p) for p in pairs]
        out: list = [None if any(x.__class__ is bool for x in p) else self._memo.get(p) for p in pairs]
        missing = [i for i, v in enumerate(out) if v is None]
        if missing:
            keys = [self.key(*pairs[i]) for i in missing]
            if self.local is not None:
                values = self.local.get_many(keys, estimate)
            else:
                import ray

                values = ray.get(self.service.get_many.remote(keys, estimate))
            for i, value in zip(missing, values):
                out[i] = value
                if value.estimate is None:
                    self._memo[pairs[i]] = value
        return out
