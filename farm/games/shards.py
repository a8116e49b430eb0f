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

from farm.core.output import write_table
from workers import CaptureStats, Case, results_statistics, run_games
from workers.engine import estimated_game_seconds

__all__ = ["SHARD_SECONDS", "MAX_SHARD_GAMES", "SWEEP_ID_KEY", "ROWS_SHA256_KEY", "rows_sha256", "shard_problem",
           "games_per_shard", "shard_ranges", "play_shard", "play_outcomes",
           "write_shard", "warn_coarse_steps"]

SHARD_SECONDS = 0.5
MAX_SHARD_GAMES = 100_000


def games_per_shard(case: Case) -> int:
    """Games per Ray task: about half a second of work on one core by the engine's cost
    model, so that the cost of a task beyond its games (Ray's dispatch and the shard's atomic
    Parquet write, timed by benchmarks/farm.py: docs/results.md) stays under 5%."""
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
ROWS_SHA256_KEY = "swarm_farm.rows_sha256"  # ... and the checksum of their rows (rows_sha256)


def write_shard(df: pd.DataFrame, path: Path, sweep_id: str | None = None) -> Path:
    """Write a shard's rows to path (a .parquet file) atomically, with the id of the sweep it
    belongs to (SWEEP_ID_KEY) and the checksum of its rows (ROWS_SHA256_KEY, rows_sha256) in
    the file's metadata; returns path."""
    import pyarrow as pa

    metadata = {ROWS_SHA256_KEY: rows_sha256(pa.Table.from_pandas(df, preserve_index=False))}
    if sweep_id:
        metadata[SWEEP_ID_KEY] = sweep_id
    return write_table(df, Path(path).with_suffix(""), "parquet", metadata=metadata)


def rows_sha256(table) -> str:
    """The SHA-256 of a shard's rows (a pyarrow.Table): every column's name, type and values,
    in order, whatever the table's chunks or schema metadata, so that the table written and
    the table read back from its Parquet file give the same digest, and a changed value
    another."""
    import hashlib

    import pyarrow as pa

    digest = hashlib.sha256()
    for name, column in zip(table.column_names, table.columns):
        array = column.combine_chunks() if column.num_chunks else pa.array([], column.type)
        listed = pa.types.is_list(array.type) or pa.types.is_large_list(array.type)
        # a list's item field is `item` in memory, `element` read back from Parquet: its type is its values'
        digest.update(f"{name}:{f'list<{array.type.value_type}>' if listed else array.type};".encode())
        if listed:
            offsets = array.offsets.to_numpy()
            digest.update(np.ascontiguousarray(offsets - offsets[0]).tobytes())
            array = array.flatten()
        if array.null_count:
            digest.update(np.ascontiguousarray(array.is_null().to_numpy(zero_copy_only=False)).tobytes())
        if pa.types.is_integer(array.type) or pa.types.is_floating(array.type) or pa.types.is_boolean(array.type):
            digest.update(np.ascontiguousarray(array.to_numpy(zero_copy_only=False)).tobytes())
        else:
            digest.update(repr(array.to_pylist()).encode())
    return digest.hexdigest()


def shard_problem(path: Path, sweep_id: str, point: int, number: int, start: int, stop: int):
    """(the shard's rows as a DataFrame, None) when the file at path is shard `number` of
    point `point` (games start..stop-1) of sweep sweep_id, whole; else (None, what is wrong:
    unreadable, of another sweep, failing its checksum, or rows of other games or another
    shard, as when a shard was copied over another's name). Files without the checksum (no
    ROWS_SHA256_KEY) or without the sweep id (older formats) are judged by their rows alone."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except Exception as e:  # noqa: BLE001 - a damaged file fails in many ways inside pyarrow
        return None, f"unreadable ({type(e).__name__})"
    meta = table.schema.metadata or {}
    found = meta.get(SWEEP_ID_KEY.encode(), b"").decode(errors="replace")
    if found and found != sweep_id:
        return None, f"belongs to sweep {found}, not {sweep_id}"
    expected = meta.get(ROWS_SHA256_KEY.encode())
    try:
        if expected is not None and rows_sha256(table) != expected.decode(errors="replace"):
            return None, "fails its checksum"
        df = table.to_pandas()
        if len(df) != stop - start:
            return None, f"holds {len(df)} games, not the {stop - start} of games {start}..{stop - 1}"
        for column, want in (("point", np.full(stop - start, point)), ("shard", np.full(stop - start, number)),
                             ("game", np.arange(start, stop))):
            if column not in df.columns or not np.array_equal(df[column].to_numpy(), want):
                return None, f"holds other rows than point {point}'s games {start}..{stop - 1} (its `{column}`)"
    except (pa.ArrowException, ValueError, TypeError) as e:
        return None, f"unreadable ({type(e).__name__})"
    return df, None
