"""Monte Carlo cases: the game model (Case), initial-position laws, per-game
statistics and per-case summaries (CaptureStats).

`Case` is the one definition of a game's parameters, with their defaults,
normalisation and validation; configs, the service's keys and the CLI are built
from it (docs/model.md sections 1-4).

Seeding (docs/model.md section 6): game g of a case with seed s draws its initial
positions from ``numpy.random.default_rng([*s, g])`` (s an int or a tuple of ints)
and from nothing else, so game g is the same game whoever plays it (run_case, a
sweep's shard on any worker, the capture-time service) and however its games are
cut into batches. Cases with the same seed share their streams (common random numbers).

Censoring (docs/model.md section 4): an evader not captured by t_max has capture time
NaN. Per game, `first_capture` is NaN when nobody was captured, `last_capture`
(the game's end) is NaN unless everybody was, `mean_capture` averages the
captured evaders only; fractions count uncaptured evaders as not captured.
Escapes (a Case with an exit_point) are treated the same way: an evader
that never escaped has escape time NaN, `first_escape` / `mean_escape` are NaN
when nobody escaped, and without an exit point every escape column says nobody
escaped. Per case, time statistics are over the games where the quantity is
finite, and `n_censored` says how many games were left out.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np
import pandas as pd

from workers.arena import make_arena
from workers.engine import ENGINE_VERSION, simulate_games
from workers.errors import InputError, point, positive
from workers.policies import get_evader_policy, get_pursuer_policy

__all__ = [
    "InitialLaw",
    "PAPER_LAW",
    "Case",
    "sample_initial_positions",
    "run_games",
    "simulate_case",
    "game_statistics",
    "results_statistics",
    "TimeSummary",
    "CaptureStats",
    "run_case",
    "TIME_METRICS",
    "SEEDING",
    "GAME_FIELDS",
]

Box = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max
TIME_METRICS = ("first_capture", "mean_capture", "last_capture", "first_escape", "mean_escape")
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
SEEDING = "default_rng([*seed, game])"  # part of every sweep's id: sweeps seeded otherwise are never mixed in


@dataclass(frozen=True)
class InitialLaw:
    """How initial positions are drawn, independently and uniformly.

    kind "boxes": pursuers in pursuer_box, evaders in evader_box (each
    (x_min, x_max, y_min, y_max)); kind "uniform": everyone uniform in the arena.
    """

    __pydantic_config__ = {"extra": "forbid"}  # read from configs by pydantic: unknown names are errors

    kind: Literal["boxes", "uniform"] = "boxes"
    pursuer_box: Box = (3.0, 5.0, 0.0, 10.0)
    evader_box: Box = (7.0, 9.0, 0.0, 10.0)


PAPER_LAW = InitialLaw()


@dataclass(frozen=True)
class Case:
    """A game's parameters: everything that changes a Monte Carlo case's numbers
    (docs/model.md section 4), the engine's version included. Build with Case(n_p, n_e,
    **settings) from code, or with farm.config.case_from(mapping) from config values."""

    __pydantic_config__ = {"extra": "forbid"}  # read from configs by pydantic: unknown names are errors

    n_pursuers: int
    n_evaders: int
    pursuer_policy: str = "area_min"
    evader_policy: str = "centroid"
    capture_radius: float = 0.25
    dt: float = 0.01
    t_max: float = 60.0
    tau: float = 5.0
    target: tuple[float, float] = (0.0, 5.0)
    arena: tuple[tuple[float, float], ...] | None = None
    law: InitialLaw = field(default_factory=InitialLaw)
    exit_point: tuple[float, float] | None = None  # None: no escapes (the paper's games)
    pursuer_speed: float = 1.0
    evader_speed: float = 1.0
    engine_version: str = ENGINE_VERSION

    def __post_init__(self):
        # One spelling per value, so that 60 and 60.0 give the same key.
        def num(v):
            return float(v) if isinstance(v, (int, float, np.number)) and not isinstance(v, bool) else v

        for name in _POSITIVE_FIELDS:
            object.__setattr__(self, name, num(getattr(self, name)))
        for name in ("n_pursuers", "n_evaders"):
            v = getattr(self, name)
            if isinstance(v, np.integer):
                object.__setattr__(self, name, int(v))
        for name in _POINT_FIELDS:
            v = getattr(self, name)
            if isinstance(v, (tuple, list, np.ndarray)):
                object.__setattr__(self, name, tuple(num(x) for x in v))
        if isinstance(self.arena, (tuple, list)):
            object.__setattr__(self, "arena", tuple(tuple(num(x) for x in v) for v in self.arena))
        if isinstance(self.law, InitialLaw):
            object.__setattr__(self, "law", InitialLaw(self.law.kind, tuple(num(x) for x in self.law.pursuer_box),
                                                       tuple(num(x) for x in self.law.evader_box)))

    def validate(self) -> "Case":
        for name in ("n_pursuers", "n_evaders"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise InputError(f"{name}: must be a whole number >= 1, got {v!r}")
        get_pursuer_policy(self.pursuer_policy)
        get_evader_policy(self.evader_policy)
        for name in _POSITIVE_FIELDS:
            positive(name, getattr(self, name))
        for name in _POINT_FIELDS:
            if name != "exit_point" or self.exit_point is not None:
                point(name, getattr(self, name))
        arena = make_arena(self.arena)
        if self.law.kind == "boxes":
            for name in ("pursuer_box", "evader_box"):
                box = getattr(self.law, name)
                if len(box) != 4 or box[0] > box[1] or box[2] > box[3]:
                    raise InputError(f"law.{name}: must be (x_min, x_max, y_min, y_max), got {box!r}")
                corners = np.array([[box[0], box[2]], [box[1], box[2]], [box[1], box[3]], [box[0], box[3]]])
                if not arena.contains(corners).all():
                    raise InputError(f"law.{name}: {box!r} is not inside the arena")
        elif self.law.kind != "uniform":
            raise InputError(f"law.kind: must be 'boxes' or 'uniform', got {self.law.kind!r}")
        return self

    def to_dict(self) -> dict:
        return json.loads(json.dumps(asdict(self)))

    def key(self) -> str:
        """A stable hash of every parameter, the engine's version included."""
        blob = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


# Field names by kind, for normalisation and validation (Case's numbers).
_POSITIVE_FIELDS = ("capture_radius", "dt", "t_max", "tau", "pursuer_speed", "evader_speed")
_POINT_FIELDS = ("target", "exit_point")
# The game settings a config may name (the engine's version is not a setting).
GAME_FIELDS = tuple(name for name in Case.__dataclass_fields__ if name != "engine_version")


def _seed_words(seed) -> list[int]:
    words = list(seed) if isinstance(seed, (tuple, list)) else [seed]
    for w in words:
        if isinstance(w, bool) or not isinstance(w, (int, np.integer)) or w < 0:
            raise InputError(f"seed: must be a whole number >= 0 (or a tuple of them), got {seed!r}")
    return [int(w) for w in words]


def sample_initial_positions(case: Case, seed, start: int, stop: int):
    """Initial positions of games start..stop-1 of a case.

    seed: int or tuple of ints. Returns pursuers (stop-start, n_p, 2) and evaders (stop-start, n_e, 2) float64;
    game i uses default_rng([*seed, i]) alone.
    """
    words = _seed_words(seed)
    n_p, n_e = case.n_pursuers, case.n_evaders
    arena = make_arena(case.arena)
    pursuers = np.empty((stop - start, n_p, 2))
    evaders = np.empty((stop - start, n_e, 2))
    for row, game in enumerate(range(start, stop)):
        rng = np.random.default_rng([*words, game])
        if case.law.kind == "uniform":
            pursuers[row] = arena.sample_uniform(rng, (n_p,))
            evaders[row] = arena.sample_uniform(rng, (n_e,))
        else:
            pursuers[row] = _in_box(rng, case.law.pursuer_box, n_p)
            evaders[row] = _in_box(rng, case.law.evader_box, n_e)
    return pursuers, evaders


def _in_box(rng: np.random.Generator, box: Box, n: int) -> np.ndarray:
    lo = np.array([box[0], box[2]])
    hi = np.array([box[1], box[3]])
    return lo + (hi - lo) * rng.random((n, 2))


def run_games(case: Case, seed, start: int, stop: int, *, record: bool = False):
    """Simulate games start..stop-1 of a case in one batch; returns GameResults."""
    pursuers, evaders = sample_initial_positions(case, seed, start, stop)
    return simulate_case(case, pursuers, evaders, record=record)


def simulate_case(case: Case, pursuers, evaders, *, record: bool = False):
    """Simulate games of a case's settings from given starts: pursuers (B, n_p, 2) and
    evaders (B, n_e, 2) float64 (the team sizes are the arrays'); returns GameResults."""
    return simulate_games(
        pursuers,
        evaders,
        pursuer_policy=case.pursuer_policy,
        evader_policy=case.evader_policy,
        capture_radius=case.capture_radius,
        dt=case.dt,
        t_max=case.t_max,
        target=case.target,
        arena=case.arena,
        record=record,
        exit_point=case.exit_point,
        pursuer_speed=case.pursuer_speed,
        evader_speed=case.evader_speed,
    )


def game_statistics(capture_times: np.ndarray, tau: float, first_game: int = 0,
                    escape_times: np.ndarray | None = None) -> pd.DataFrame:
    """Per-game statistics, one row per game.

    capture_times: (B, n_e) float64, NaN = not captured; escape_times: (B, n_e)
    float64, NaN = did not escape, or None for games without an exit (nobody escaped).

    Columns: game (int64), first_capture, mean_capture, last_capture, frac_captured,
    frac_captured_tau, all_captured_tau (bool), frac_escaped, frac_escaped_tau,
    first_escape, mean_escape (float64). A time within tau + 1e-9 counts as within tau.
    """
    ct = np.asarray(capture_times, dtype=np.float64)
    et = np.full(ct.shape, np.nan) if escape_times is None else np.asarray(escape_times, dtype=np.float64)
    if et.shape != ct.shape:
        raise InputError(f"escape_times: must have the shape of capture_times {ct.shape}, got {et.shape}")
    n_e = ct.shape[1]
    captured = _event_stats(ct, tau)
    escaped = _event_stats(et, tau)
    with np.errstate(invalid="ignore"):
        last = np.where(captured["all"], np.max(np.where(np.isfinite(ct), ct, 0.0), axis=1), np.nan)
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
        }
    )


def results_statistics(res, tau: float, first_game: int = 0) -> pd.DataFrame:
    """game_statistics of a GameResults' capture and escape times."""
    return game_statistics(res.capture_times, tau, first_game=first_game, escape_times=res.escape_times)


def _event_stats(times: np.ndarray, tau: float) -> dict[str, np.ndarray]:
    """Per game of times (B, n_e) float64, NaN = the event did not happen: n and n_tau
    (B,) int64, counts by t_max and by tau; first and mean (B,) float64, NaN when no
    event; all and all_tau (B,) bool."""
    happened = np.isfinite(times)
    n = happened.sum(axis=1)
    some = n > 0
    within = happened & (times <= tau + 1e-9)  # event times are step * dt: 35 * 0.01 > 0.35
    with np.errstate(invalid="ignore"):
        first = np.where(some, np.nanmin(np.where(some[:, None], times, 0.0), axis=1), np.nan)
        mean = np.where(some, np.nansum(times, axis=1) / np.maximum(n, 1), np.nan)
    return {"n": n, "n_tau": within.sum(axis=1), "first": first, "mean": mean,
            "all": happened.all(axis=1), "all_tau": within.all(axis=1)}


TIME_STATS = ("mean", "std", "ci95_low", "ci95_high", "min", "max", "q05", "q25", "q50", "q75", "q95",
              "n_censored")


@dataclass(frozen=True)
class TimeSummary:
    """One time metric over a case's games: statistics of the games where it is finite
    (std with ddof=1, a Student-t 95% CI on the mean, quantiles), NaN when there are none
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
        """times: (B,) float64 per game, NaN = censored."""
        from scipy import stats

        x = times[np.isfinite(times)]
        n = len(x)
        if n == 0:
            return cls(*[math.nan] * 11, n_censored=len(times))
        mean = float(np.mean(x))
        std = float(np.std(x, ddof=1)) if n > 1 else math.nan
        half = float(stats.t.ppf(0.975, n - 1) * std / math.sqrt(n)) if n > 1 else math.nan
        q = [float(v) for v in np.quantile(x, QUANTILES)]
        return cls(mean, std, mean - half, mean + half, float(np.min(x)), float(np.max(x)), *q,
                   n_censored=int(len(times) - n))


# CaptureStats' fractions: the per-game column each averages, and its name in the flat layout
# (sweep summaries, the store's rows).
_FRACTIONS = {"frac_captured": ("frac_captured", "frac_captured_mean"),
              "frac_captured_tau": ("frac_captured_tau", "frac_captured_tau_mean"),
              "p_all_captured_tau": ("all_captured_tau", "p_all_captured_tau"),
              "frac_escaped": ("frac_escaped", "frac_escaped_mean"),
              "frac_escaped_tau": ("frac_escaped_tau", "frac_escaped_tau_mean")}
# Keys the capture-time store wrote beside the statistics before CaptureStats (read, not written).
_FORMER_KEYS = {"expected_frac_captured_tau", "estimate", "estimate_method", "key"}


@dataclass(frozen=True)
class CaptureStats:
    """A case's statistics over its games (docs/model.md section 4): what run_case returns
    and what the capture-time service answers.

    frac_captured / frac_captured_tau: mean over games of the fraction of evaders captured
    by t_max / within tau (the allocation env's expected share of intruders removed);
    p_all_captured_tau: share of games with every evader captured within tau; the escape
    fractions likewise; one TimeSummary per time metric of TIME_METRICS. estimate: None
    for statistics of played games; for the service's interpolation of neighbouring cases,
    how it was made (n_games is then 0).
    """

    n_games: int
    frac_captured: float
    frac_captured_tau: float
    p_all_captured_tau: float
    frac_escaped: float
    frac_escaped_tau: float
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
        """One flat row: n_games, m_<stat> for every time metric m and statistic, and the
        fractions as frac_captured_mean, frac_captured_tau_mean, p_all_captured_tau,
        frac_escaped_mean, frac_escaped_tau_mean (a sweep's summary columns)."""
        out: dict = {"n_games": self.n_games}
        for m in TIME_METRICS:
            out.update({f"{m}_{s}": v for s, v in asdict(getattr(self, m)).items()})
        out.update({flat: getattr(self, name) for name, (_, flat) in _FRACTIONS.items()})
        return out

    @classmethod
    def from_flat(cls, row: dict, estimate: str | None = None) -> "CaptureStats":
        """The inverse of flat(); also reads the store's rows written before CaptureStats."""
        unknown = set(row) - set(cls.flat_names()) - _FORMER_KEYS
        if unknown:
            raise InputError(f"CaptureStats: unknown fields {', '.join(sorted(unknown))}")
        times = {m: TimeSummary(**{s: row[f"{m}_{s}"] for s in TIME_STATS}) for m in TIME_METRICS}
        fractions = {name: row[flat] for name, (_, flat) in _FRACTIONS.items()}
        return cls(n_games=int(row["n_games"]), **fractions, **times, estimate=estimate)

    @staticmethod
    def flat_names() -> tuple[str, ...]:
        return ("n_games", *(f"{m}_{s}" for m in TIME_METRICS for s in TIME_STATS),
                *(flat for _, flat in _FRACTIONS.values()))


def run_case(case: Case, n_games: int, seed, *, batch_size: int = 1024, progress=None):
    """Run games 0..n_games-1 of a case in batches; returns (per_game DataFrame, CaptureStats).

    progress: optional callable(games_done) called after each batch.
    """
    case.validate()
    if not isinstance(n_games, (int, np.integer)) or n_games < 1:
        raise InputError(f"n_games: must be a whole number >= 1, got {n_games!r}")
    frames = []
    for start in range(0, n_games, batch_size):
        stop = min(n_games, start + batch_size)
        res = run_games(case, seed, start, stop)
        frames.append(results_statistics(res, case.tau, first_game=start))
        if progress is not None:
            progress(stop)
    per_game = pd.concat(frames, ignore_index=True)
    return per_game, CaptureStats.from_games(per_game)
