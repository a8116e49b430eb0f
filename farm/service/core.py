"""Computing and estimating a key's statistics (no Ray here)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from workers import game_statistics, run_games, summarize_case

from farm.config import default_shard_games
from farm.service.keys import StatsKey

ESTIMATE_NEIGHBOURS = 4


def shard_ranges(key: StatsKey) -> list[tuple[int, int]]:
    step = default_shard_games(key.case)
    return [(a, min(key.games, a + step)) for a in range(0, key.games, step)]


def compute_shard(key: StatsKey, start: int, stop: int) -> pd.DataFrame:
    """Per-game statistics of games start..stop-1 of a key (game g seeded by [seed, g])."""
    res = run_games(key.case, (key.seed,), start, stop)
    return game_statistics(res.capture_times, key.case.tau, first_game=start, escape_times=res.escape_times)


def stats_from_games(key: StatsKey, per_game: pd.DataFrame) -> dict:
    """The service's value (SPEC.md section 4): summarize_case's numbers, plus
    expected_frac_captured_tau (the fraction of intruders caught within tau)."""
    value = summarize_case(per_game.sort_values("game"))
    value["expected_frac_captured_tau"] = value["frac_captured_tau_mean"]
    value["estimate"] = False
    value["key"] = key.digest()
    return value


def compute_in_process(key: StatsKey) -> dict:
    frames = [compute_shard(key, a, b) for a, b in shard_ranges(key)]
    return stats_from_games(key, pd.concat(frames, ignore_index=True))


def estimate(key: StatsKey, neighbours: list[tuple[int, int, dict]]) -> dict | None:
    """Inverse-distance (power 2) average over the nearest stored (n_p, n_e) of the
    same settings; None without neighbours. Flagged as an estimate, with its method."""
    if not neighbours:
        return None
    n_p, n_e = key.sizes
    d = np.array([math.hypot(a - n_p, b - n_e) for a, b, _ in neighbours])
    nearest = np.argsort(d, kind="stable")[:ESTIMATE_NEIGHBOURS]
    w = 1.0 / d[nearest] ** 2
    w /= w.sum()
    values = [neighbours[i][2] for i in nearest]
    out: dict = {}
    for name, v in values[0].items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            xs = np.array([float(x[name]) if x.get(name) is not None else np.nan for x in values])
            ok = np.isfinite(xs)
            out[name] = float(np.sum(w[ok] * xs[ok]) / np.sum(w[ok])) if ok.any() else math.nan
    used = ", ".join(f"({neighbours[i][0]},{neighbours[i][1]})" for i in nearest)
    out.update(
        estimate=True,
        n_games=0,
        key=key.digest(),
        estimate_method=f"inverse-distance (power 2) over the {len(nearest)} nearest stored (n_p, n_e): {used}",
    )
    return out
