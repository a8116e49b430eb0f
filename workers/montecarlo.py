"""Monte Carlo cases: drawing a case's initial positions, playing its games and
summarising them (the game model is workers.case, the statistics workers.stats).

Seeding (docs/model.md section 6): game g of a case with seed s draws its initial
positions from ``numpy.random.default_rng([*s, g])`` (s an int or a tuple of ints)
and from nothing else, so game g is the same game whoever plays it (run_case, a
sweep's shard on any worker, the capture-time service) and however its games are
cut into batches. Cases with the same seed share their streams (common random numbers).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from workers.arena import make_arena
from workers.case import Box, Case
from workers.engine import GameResults, simulate_games
from workers.errors import InputError, is_whole, shown, whole
from workers.stats import CaptureStats, results_statistics

__all__ = ["sample_initial_positions", "run_games", "simulate_case", "run_case", "SEEDING", "MAX_GAMES",
           "MAX_BATCH_BYTES"]

MAX_GAMES = 10**9  # games of one run_case: far above any Monte Carlo case (the farm shards millions)
MAX_BATCH_BYTES = 2**32  # the starting positions of one batch (run_games, sample_initial_positions): 4 GiB

SEEDING = "default_rng([*seed, game])"  # part of every sweep's id: sweeps seeded otherwise are never mixed in


def _checked_case(case) -> Case:
    """The Case validated; a one-line InputError when it is not a Case (a dict, say) or is invalid."""
    if not isinstance(case, Case):
        raise InputError(f"case: expected a workers.Case, got {type(case).__name__}; build one with "
                         "Case(n_p, n_e, ...) or farm.core.config.case_from(mapping)", field="case")
    return case.validate()


def _seed_words(seed) -> list[int]:
    words = list(seed) if isinstance(seed, (tuple, list)) else [seed]
    for w in words:
        if not is_whole(w) or w < 0:
            raise InputError(f"seed: must be a whole number >= 0 (or a tuple of them), got {shown(seed)}", field="seed")
    return [int(w) for w in words]


def sample_initial_positions(case: Case, seed, start: int, stop: int):
    """Initial positions of games start..stop-1 of a case.

    seed: int or tuple of ints; 0 <= start <= stop (else InputError, as for an invalid
    case). Returns pursuers: (stop-start, n_p, 2) and evaders: (stop-start, n_e, 2)
    float64; game i uses default_rng([*seed, i]) alone.
    """
    return _initial_positions(_checked_case(case), seed, start, stop)


def _initial_positions(case: Case, seed, start, stop):
    """sample_initial_positions of a case already validated."""
    words = _seed_words(seed)
    start = whole("start", start, 0)
    stop = whole("stop", stop, start)
    n_p, n_e = case.n_pursuers, case.n_evaders
    needed = (stop - start) * (n_p + n_e) * 2 * 8
    if needed > MAX_BATCH_BYTES:
        gib = f"{needed / 2**30:.3g}" if needed < 2**1000 else f"about 1e{int(math.log10(needed) - 9.03)}"
        raise InputError(f"stop: games {start}..{shown(stop)} of {n_p} v {n_e} need {gib} GiB of "
                         f"starting positions in one batch, more than {MAX_BATCH_BYTES // 2**30} GiB; play them "
                         f"in batches (run_case, or a sweep's shards)", field="stop")
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


def run_games(case: Case, seed, start: int, stop: int, *, record: bool = False) -> GameResults:
    """Simulate games start..stop-1 of a case in one batch; returns GameResults.

    An invalid case, seed, start or stop raises InputError."""
    case = _checked_case(case)
    pursuers, evaders = _initial_positions(case, seed, start, stop)
    return _simulate(case, pursuers, evaders, record)


def simulate_case(case: Case, pursuers, evaders, *, record: bool = False) -> GameResults:
    """Simulate games of a case's settings from given starts; returns GameResults.

    pursuers: (B, n_p, 2) float64, evaders: (B, n_e, 2) float64 (the team sizes are the
    arrays', not the case's). An invalid case raises InputError."""
    return _simulate(_checked_case(case), pursuers, evaders, record)


def _simulate(case: Case, pursuers, evaders, record) -> GameResults:
    """simulate_case of a case already validated."""
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


def run_case(case: Case, n_games: int, seed, *, batch_size: int = 1024,
             progress=None) -> tuple[pd.DataFrame, CaptureStats]:
    """Run games 0..n_games-1 of a case in batches; returns (per_game DataFrame, CaptureStats).

    per_game has game_statistics' columns, one row per game; progress: optional
    callable(games_done) called after each batch. An invalid case (a window tau longer than
    its games too: Case.check_window), n_games, seed, batch_size or progress raises InputError.
    """
    case = _checked_case(case).check_window()
    n_games = whole("n_games", n_games, 1)
    if n_games > MAX_GAMES:
        raise InputError(f"n_games: must be at most {MAX_GAMES:,} (one run_case's table holds a row a game), "
                         f"got {shown(n_games)}", field="n_games")
    batch_size = whole("batch_size", batch_size, 1)
    _seed_words(seed)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: must be a callable or None, got {type(progress).__name__}", field="progress")
    frames = []
    for start in range(0, n_games, batch_size):
        stop = min(n_games, start + batch_size)
        pursuers, evaders = _initial_positions(case, seed, start, stop)
        res = _simulate(case, pursuers, evaders, False)
        frames.append(results_statistics(res, case.tau, first_game=start))
        if progress is not None:
            progress(stop)
    per_game = pd.concat(frames, ignore_index=True)
    return per_game, CaptureStats.from_games(per_game)
