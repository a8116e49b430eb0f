"""Computing and estimating a key's statistics (no Ray here)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from workers import CaptureStats, results_statistics, run_games

from farm.config import default_shard_games
from farm.service.keys import StatsKey

ESTIMATE_NEIGHBOURS = 4


def shard_ranges(key: StatsKey) -> list[tuple[int, int]]:
    step = default_shard_games(key.case)
    return [(a, min(key.games, a + step)) for a in range(0, key.games, step)]


def compute_shard(key: StatsKey, start: int, stop: int) -> pd.DataFrame:
    """Per-game statistics of games start..stop-1 of a key's case with its seed (game g is
    default_rng([seed, g]), as everywhere: docs/model.md section 6)."""
    res = run_games(key.case, key.seed, start, stop)
    return results_statistics(res, key.case.tau, first_game=start)


def stats_from_games(per_game: pd.DataFrame) -> CaptureStats:
    """The service's value (docs/model.md section 4) of a key's games, in any order."""
    return CaptureStats.from_games(per_game.sort_values("game", kind="stable"))


def compute_in_process(key: StatsKey) -> CaptureStats:
    frames = [compute_shard(key, a, b) for a, b in shard_ranges(key)]
    return stats_from_games(pd.concat(frames, ignore_index=True))


class NeighbourIndex:
    """The computed cases of each setting by team sizes, in memory, for estimates: reading
    them from the store on every miss would parse and verify every row of the setting."""

    def __init__(self, store, cache: dict[str, CaptureStats]):
        """store: a StatsStore; cache: digest -> value of its sound rows (store.load_all())."""
        self._by_settings: dict[str, dict[tuple[int, int], CaptureStats]] = {}
        for digest, settings, n_p, n_e in store.sizes():
            if digest in cache:
                self._by_settings.setdefault(settings, {})[(n_p, n_e)] = cache[digest]

    def add(self, key: StatsKey, value: CaptureStats) -> None:
        self._by_settings.setdefault(key.settings_digest(), {})[key.sizes] = value

    def neighbours(self, key: StatsKey) -> list[tuple[int, int, CaptureStats]]:
        """Computed cases with the same settings as key: (n_p, n_e, value)."""
        return [(n_p, n_e, v) for (n_p, n_e), v in self._by_settings.get(key.settings_digest(), {}).items()]


def estimate(key: StatsKey, neighbours: list[tuple[int, int, CaptureStats]]) -> CaptureStats | None:
    """Inverse-distance (power 2) average of every statistic over the nearest stored
    (n_p, n_e) of the same settings (n_games 0, `estimate` saying how); None without neighbours."""
    if not neighbours:
        return None
    n_p, n_e = key.sizes
    sizes = np.array([(a, b) for a, b, _ in neighbours], dtype=np.float64)
    d = np.hypot(sizes[:, 0] - n_p, sizes[:, 1] - n_e)
    nearest = np.argsort(d, kind="stable")[:ESTIMATE_NEIGHBOURS]
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
    return CaptureStats.from_flat(
        out, estimate=f"inverse-distance (power 2) over the {len(nearest)} nearest stored (n_p, n_e): {used}")
