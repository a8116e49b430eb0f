"""Shards: a case's games cut into runs of about half a second, each played and written the
same way whoever asks (a sweep, the capture-time service, the games-fidelity evaluation).

Game g of a case with seed s is game g whatever shard plays it (its initial positions come
from ``default_rng([s, g])`` alone, docs/model.md section 6), so shard boundaries, the number
of workers and retries never change a number. The Ray task that plays a shard is in
farm.games.tasks; this module has no Ray.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from workers import Case, CaptureStats, results_statistics, run_games
from workers.engine import estimated_game_seconds

from farm.core.output import write_table

__all__ = ["SHARD_SECONDS", "MAX_SHARD_GAMES", "SWEEP_ID_KEY", "games_per_shard", "shard_ranges", "play_shard", "play_outcomes",
           "write_shard", "warn_coarse_steps"]

SHARD_SECONDS = 0.5
MAX_SHARD_GAMES = 100_000


def games_per_shard(case: Case) -> int:
    """Games per Ray task: about half a second of work on one core by the engine's cost
    model, so that the cost of a task beyond its games (Ray's dispatch and the shard's atomic
    Parquet write, 10-20 ms measured by benchmarks/farm.py) stays under 5%."""
    seconds = estimated_game_seconds(case.n_pursuers, case.n_evaders, case.pursuer_policy, case.evader_policy,
                                     case.t_max, case.dt, case.pursuer_speed, case.evader_speed)
    return int(min(MAX_SHARD_GAMES, max(1, round(SHARD_SECONDS / seconds))))


def warn_coarse_steps(cases) -> None:
    """One CoarseStepWarning for the coarsest of cases whose agents move more than the capture
    radius a step, said by the driver (the games' own warnings stay in the Ray workers)."""
    from workers.engine import coarse_step_ratio, warn_coarse_step

    cases = list(cases)
    if cases:
        worst = max(cases, key=lambda c: coarse_step_ratio(max(c.pursuer_speed, c.evader_speed), c.dt,
                                                           c.capture_radius))
        warn_coarse_step(max(worst.pursuer_speed, worst.evader_speed), worst.dt, worst.capture_radius, stacklevel=2)


def shard_ranges(games: int, per_shard: int) -> list[tuple[int, int]]:
    """(first game, end game) of each shard of games 0..games-1, per_shard games a shard
    (the last one shorter)."""
    return [(a, min(games, a + per_shard)) for a in range(0, games, per_shard)]


def play_shard(case: Case, seed, start: int, stop: int, *, detail: bool = False) -> pd.DataFrame:
    """Per-game statistics of games start..stop-1 of a case (workers.game_statistics' columns,
    one row a game). detail: also each game's `steps` (int64) and its evaders' `capture_times`
    and `escape_times` (lists of n_e float64, NaN where it did not happen), as a sweep's
    shard files keep them."""
    res = run_games(case, seed, start, stop)
    df = results_statistics(res, case.tau, first_game=start)
    if detail:
        df["steps"] = res.steps
        df["capture_times"] = list(res.capture_times)
        df["escape_times"] = list(res.escape_times)
    return df


def play_outcomes(case: Case, seed, start: int, stop: int):
    """Games start..stop-1 of a case summed up where they are played: (their CaptureStats,
    capture_times: (stop - start, n_e) float64, NaN where an evader was not caught), what a
    live engagement needs, a fraction of play_shard's rows to send back."""
    rows = play_shard(case, seed, start, stop, detail=True)
    return CaptureStats.from_games(rows), np.stack(rows["capture_times"].to_list())


SWEEP_ID_KEY = "swarm_farm.sweep_id"  # a sweep's shard files carry its id in their Parquet metadata


def write_shard(df: pd.DataFrame, path: Path, sweep_id: str | None = None) -> Path:
    """Write a shard's rows to path (a .parquet file) atomically, with the id of the sweep it
    belongs to in the file's metadata (SWEEP_ID_KEY); returns path."""
    return write_table(df, Path(path).with_suffix(""), "parquet",
                       metadata={SWEEP_ID_KEY: sweep_id} if sweep_id else None)
