"""Statistics of played games: per game (game_statistics) and per case (CaptureStats).

Censoring (docs/model.md section 4): an evader not captured by t_max has capture time
NaN. Per game, `first_capture` is NaN when nobody was captured, `last_capture`
(the game's end) is NaN unless everybody was, `mean_capture` averages the
captured evaders only; fractions count uncaptured evaders as not captured.
Escapes (a Case with an exit_point) are treated the same way: an evader
that never escaped has escape time NaN, `first_escape` / `mean_escape` are NaN
when nobody escaped, and without an exit point every escape column says nobody
escaped. Per case, time statistics are over the games where the quantity is
finite, and `n_censored` says how many games were left out.

The capture score (docs/model.md section 5) is an expectation over all games: per game,
`capture_score_tau` is the mean over its evaders of max(0, 1 - t/tau), an evader not
captured within tau scoring 0; per case, the mean over every game, censored or not.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from workers.errors import InputError

__all__ = [
    "mean_ci95",
    "game_statistics",
    "results_statistics",
    "TimeSummary",
    "CaptureStats",
    "TIME_METRICS",
    "TIME_STATS",
    "QUANTILES",
]

TIME_METRICS = ("first_capture", "mean_capture", "last_capture", "first_escape", "mean_escape")
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
TIME_STATS = ("mean", "std", "ci95_low", "ci95_high", "min", "max", "q05", "q25", "q50", "q75", "q95",
              "n_censored")


def game_statistics(capture_times: np.ndarray, tau: float, first_game: int = 0,
                    escape_times: np.ndarray | None = None) -> pd.DataFrame:
    """Per-game statistics, one row per game.

    capture_times: (B, n_e) float64, NaN = not captured; escape_times: (B, n_e)
    float64, NaN = did not escape, or None for games without an exit (nobody escaped).

    Columns: game (int64), first_capture, mean_capture, last_capture, frac_captured,
    frac_captured_tau, all_captured_tau (bool), frac_escaped, frac_escaped_tau,
    first_escape, mean_escape, capture_score_tau (float64). A time within tau + 1e-9
    counts as within tau. capture_score_tau: the mean over the game's evaders of
    max(0, 1 - t/tau), 0 for an evader not captured within tau.
    """
    ct = np.asarray(capture_times, dtype=np.float64)
    et = np.full(ct.shape, np.nan) if escape_times is None else np.asarray(escape_times, dtype=np.float64)
    if et.shape != ct.shape:
        raise InputError(f"escape_times: must have the shape of capture_times {ct.shape}, got {et.shape}", field="escape_times")
    n_e = ct.shape[1]
    captured = _event_stats(ct, tau)
    escaped = _event_stats(et, tau)
    with np.errstate(invalid="ignore"):
        last = np.where(captured["all"], np.max(np.where(np.isfinite(ct), ct, 0.0), axis=1), np.nan)
        earliness = np.where(captured["within"], np.maximum(0.0, 1.0 - ct / tau), 0.0)
    return pd.DataFrame(
        {
            "game": np.arange(first_game, first_game + len(ct), dtype=np.int64),
            "first_capture": captured["first"],
            "mean_capture": captured["mean"],
            "last_capture": last,
            "frac_captured": captured["n"] / n_e,
            "frac_captured_tau": captured["n_tau"] / n_e,
            "all_captured_tau": captured["all_tau"],
            "frac_escaped": escaped["n"] / n_e,
            "frac_escaped_tau": escaped["n_tau"] / n_e,
            "first_escape": escaped["first"],
            "mean_escape": escaped["mean"],
            "capture_score_tau": earliness.sum(axis=1) / n_e,
        }
    )


def results_statistics(res, tau: float, first_game: int = 0) -> pd.DataFrame:
    """game_statistics of a GameResults' capture and escape times (the same columns)."""
    return game_statistics(res.capture_times, tau, first_game=first_game, escape_times=res.escape_times)


def _event_stats(times: np.ndarray, tau: float) -> dict[str, np.ndarray]:
    """Per game of times (B, n_e) float64, NaN = the event did not happen: n and n_tau
    (B,) int64, counts by t_max and by tau; first and mean (B,) float64, NaN when no
    event; all and all_tau (B,) bool; within (B, n_e) bool, the events within tau."""
    happened = np.isfinite(times)
    n = happened.sum(axis=1)
    some = n > 0
    within = happened & (times <= tau + 1e-9)  # event times are step * dt: 35 * 0.01 > 0.35
    with np.errstate(invalid="ignore"):
        first = np.where(some, np.nanmin(np.where(some[:, None], times, 0.0), axis=1), np.nan)
        mean = np.where(some, np.nansum(times, axis=1) / np.maximum(n, 1), np.nan)
    return {"n": n, "n_tau": within.sum(axis=1), "first": first, "mean": mean,
            "all": happened.all(axis=1), "all_tau": within.all(axis=1), "within": within}


@dataclass(frozen=True)
class TimeSummary:
    """One time metric over a case's games: statistics of the games where it is finite.

    std with ddof=1, a Student-t 95% CI on the mean, quantiles; NaN when there are none
    (std and the CI also for a single game); n_censored games were left out."""

    mean: float
    std: float
    ci95_low: float
    ci95_high: float
    min: float
    max: float
    q05: float
    q25: float
    q50: float
    q75: float
    q95: float
    n_censored: int

    @classmethod
    def of(cls, times: np.ndarray) -> "TimeSummary":
        """The summary of times: (B,) float64 per game, NaN = censored."""
        x = times[np.isfinite(times)]
        n = len(x)
        if n == 0:
            return cls(*[math.nan] * 11, n_censored=len(times))
        mean, half = mean_ci95(x)
        std = float(np.std(x, ddof=1)) if n > 1 else math.nan
        q = [float(v) for v in np.quantile(x, QUANTILES)]
        return cls(mean, std, mean - half, mean + half, float(np.min(x)), float(np.max(x)), *q,
                   n_censored=int(len(times) - n))


def mean_ci95(x: np.ndarray) -> tuple[float, float]:
    """(mean, half-width of the 95% Student t interval) of x: (n,) float64, n >= 1; the
    half-width is NaN for n < 2. The one t interval of swarm-farm (TimeSummary's, and every
    table of farm's with a `_ci95` column)."""
    from scipy import stats  # slow to import; only summaries need it

    if len(x) < 2:
        return float(np.mean(x)), math.nan
    return float(np.mean(x)), float(stats.t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / math.sqrt(len(x)))


# CaptureStats' fractions: the per-game column each averages, and its name in the flat layout
# (sweep summaries, the store's rows).
_FRACTIONS = {"frac_captured": ("frac_captured", "frac_captured_mean"),
              "frac_captured_tau": ("frac_captured_tau", "frac_captured_tau_mean"),
              "p_all_captured_tau": ("all_captured_tau", "p_all_captured_tau"),
              "frac_escaped": ("frac_escaped", "frac_escaped_mean"),
              "frac_escaped_tau": ("frac_escaped_tau", "frac_escaped_tau_mean"),
              "capture_score_tau": ("capture_score_tau", "capture_score_tau_mean")}
# Keys the capture-time store wrote beside the statistics before CaptureStats (read, not written).
_FORMER_KEYS = {"expected_frac_captured_tau", "estimate", "estimate_method", "key"}


@dataclass(frozen=True)
class CaptureStats:
    """A case's statistics over its games (docs/model.md section 4).

    What run_case returns and what the capture-time service answers.

    frac_captured / frac_captured_tau: mean over games of the fraction of evaders captured
    by t_max / within tau (the allocation env's expected share of intruders removed);
    p_all_captured_tau: share of games with every evader captured within tau; the escape
    fractions likewise; capture_score_tau: the mean over all games (those that caught
    nobody included) of each game's mean over its evaders of max(0, 1 - t/tau), an evader
    not captured within tau scoring 0 (the allocation env's expected capture score per
    unit of intruder mass); one TimeSummary per time metric of TIME_METRICS. estimate: None
    for statistics of played games; for the service's interpolation of neighbouring cases,
    how it was made (n_games is then 0).
    """

    n_games: int
    frac_captured: float
    frac_captured_tau: float
    p_all_captured_tau: float
    frac_escaped: float
    frac_escaped_tau: float
    capture_score_tau: float
    first_capture: TimeSummary
    mean_capture: TimeSummary
    last_capture: TimeSummary
    first_escape: TimeSummary
    mean_escape: TimeSummary
    estimate: str | None = None

    @classmethod
    def from_games(cls, per_game: pd.DataFrame) -> "CaptureStats":
        """The statistics of game_statistics rows (one per game)."""
        fractions = {name: float(per_game[column].mean()) for name, (column, _) in _FRACTIONS.items()}
        times = {m: TimeSummary.of(per_game[m].to_numpy(dtype=np.float64)) for m in TIME_METRICS}
        return cls(n_games=int(len(per_game)), **fractions, **times)

    def flat(self) -> dict:
        """The statistics as one flat row (a sweep's summary columns).

        n_games, m_<stat> for every time metric m and statistic, and the fractions as
        frac_captured_mean, frac_captured_tau_mean, p_all_captured_tau,
        frac_escaped_mean, frac_escaped_tau_mean, capture_score_tau_mean."""
        out: dict = {"n_games": self.n_games}
        for m in TIME_METRICS:
            out.update({f"{m}_{s}": v for s, v in asdict(getattr(self, m)).items()})
        out.update({flat: getattr(self, name) for name, (_, flat) in _FRACTIONS.items()})
        return out

    @classmethod
    def from_flat(cls, row: dict, estimate: str | None = None) -> "CaptureStats":
        """The inverse of flat(); also reads the store's rows of older formats (_FORMER_KEYS ignored).

        A row without a field of flat() (an older format's, e.g. without capture_score_tau_mean,
        the expected capture score) raises KeyError naming it: it is never read with a
        guessed value (the store leaves such rows out and recomputes them)."""
        unknown = set(row) - set(cls.flat_names()) - _FORMER_KEYS
        if unknown:
            raise InputError(f"CaptureStats: unknown fields {', '.join(sorted(unknown))}")
        times = {m: TimeSummary(**{s: row[f"{m}_{s}"] for s in TIME_STATS}) for m in TIME_METRICS}
        fractions = {name: row[flat] for name, (_, flat) in _FRACTIONS.items()}
        return cls(n_games=int(row["n_games"]), **fractions, **times, estimate=estimate)

    @staticmethod
    def flat_names() -> tuple[str, ...]:
        """The keys of flat(), in its order."""
        return ("n_games", *(f"{m}_{s}" for m in TIME_METRICS for s in TIME_STATS),
                *(flat for _, flat in _FRACTIONS.values()))
