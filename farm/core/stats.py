"""Means with their 95% confidence intervals, as every table of farm reports them.

mean_ci95 is workers.stats.mean_ci95 (the one Student t interval of the project);
ci_columns turns named samples into a table row's `<name>_mean`, `<name>_ci95` pair
(NaN values dropped first, both NaN without a finite value); format_ci shows a pair as
`m ± h` (just `m` without a half-width); seed_band is the band drawn around a mean
curve over seeds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from workers.stats import mean_ci95

__all__ = ["mean_ci95", "ci_columns", "format_ci", "seed_band"]


def ci_columns(samples: Mapping[str, np.ndarray]) -> dict[str, float]:
    """{f"{name}_mean": m, f"{name}_ci95": h} for each named sample (n,) float64, in order,
    over its finite values (NaN and NaN when it has none; h is NaN for one value)."""
    row: dict[str, float] = {}
    for name, values in samples.items():
        x = np.asarray(values, dtype=float)
        x = x[np.isfinite(x)]
        row[f"{name}_mean"], row[f"{name}_ci95"] = mean_ci95(x) if len(x) else (math.nan, math.nan)
    return row


def format_ci(m: float, h: float, fmt: str = ".3f") -> str:
    """`m ± h`, each number in the format fmt, or `m` alone when h is not finite (NaN: one value)."""
    return f"{m:{fmt}} ± {h:{fmt}}" if math.isfinite(h) else f"{m:{fmt}}"


def seed_band(returns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The mean over seeds of returns (S, E) float64 and the band around it: (mean, low, high),
    each (E,) float64, and the band's kind. S >= 3: the 95% t interval over seeds (mean_ci95
    at each timestep, "95% CI over seeds"); S == 2: the two seeds' min to max ("min-max of 2
    seeds"; a 95% t interval of 2 values is 12.7 standard errors wide); S == 1: no band,
    low = high = mean ("1 seed, no band")."""
    mean = returns.mean(axis=0)
    seeds = returns.shape[0]
    if seeds >= 3:
        half = np.array([mean_ci95(column)[1] for column in returns.T])
        return mean, mean - half, mean + half, "95% CI over seeds"
    if seeds == 2:
        return mean, returns.min(axis=0), returns.max(axis=0), "min-max of 2 seeds"
    return mean, mean, mean, "1 seed, no band"
