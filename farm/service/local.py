"""The service without Ray: same store, same numbers, computed in this process
(unit tests, small scripts). With estimates on, a missing key with stored
neighbours is answered by the estimate and computed on its next exact ask (there
is no background here)."""

from __future__ import annotations

from collections import Counter

from workers import CaptureStats

from farm.service.core import NeighbourIndex, compute_in_process, estimate
from farm.service.keys import StatsKey
from farm.service.store import StatsStore


class LocalService:
    def __init__(self, store_path):
        self.store = StatsStore(store_path)
        self.cache = self.store.load_all()
        self.index = NeighbourIndex(self.store, self.cache)
        self.counts = Counter()
        self.computations: Counter = Counter()

    def get_many(self, keys: list[StatsKey], estimate_missing: bool = False) -> list[CaptureStats]:
        out = []
        for key in keys:
            d = key.digest()
            value = self.cache.get(d) or self.store.get(key)
            if value is not None:
                if d not in self.cache:
                    self.index.add(key, value)
                self.cache[d] = value
                self.counts["hits"] += 1
                out.append(value)
                continue
            self.counts["misses"] += 1
            if estimate_missing:
                guess = estimate(key, self.index.neighbours(key))
                if guess is not None:
                    out.append(guess)
                    continue
            value = compute_in_process(key)
            self.store.put(key, value)
            self.cache[d] = value
            self.index.add(key, value)
            self.computations[d] += 1
            out.append(value)
        return out

    def stats(self) -> dict:
        return {**self.counts, "computations": dict(self.computations), "stored": len(self.cache),
                "corrupt_rows": list(self.store.corrupt_rows)}
