"""swarm-farm's data plane: pursuit-evasion kernels in numpy and numba (no Ray, no torch).

    from workers import simulate_games
    res = simulate_games(pursuers, evaders, pursuer_policy="area_min", evader_policy="centroid")
    res.capture_times  # (B, n_e) float64, NaN where not captured
    res.escape_times   # (B, n_e) float64, NaN where not escaped (only with exit_point=(x, y))
"""

from workers.arena import DEFAULT_ARENA, Arena, make_arena
from workers.compiled import kernel_cache
from workers.errors import InputError, SwarmFarmError

with kernel_cache():  # every compiled kernel is defined in these modules
    from workers.engine import ENGINE_VERSION, GameResults, simulate_games
    from workers.geometry import Cells, voronoi_cells
    from workers.policies import EVADER_POLICIES, PURSUER_POLICIES

__all__ = [
    "simulate_games",
    "GameResults",
    "ENGINE_VERSION",
    "InputError",
    "SwarmFarmError",
    "Arena",
    "DEFAULT_ARENA",
    "make_arena",
    "Cells",
    "voronoi_cells",
    "PURSUER_POLICIES",
    "EVADER_POLICIES",
]

from workers.montecarlo import (  # noqa: E402
    GAME_FIELDS,
    PAPER_LAW,
    SEEDING,
    CaptureStats,
    Case,
    InitialLaw,
    TimeSummary,
    game_statistics,
    results_statistics,
    run_case,
    run_games,
    sample_initial_positions,
    simulate_case,
)

__all__ += [
    "Case",
    "InitialLaw",
    "PAPER_LAW",
    "sample_initial_positions",
    "run_games",
    "simulate_case",
    "run_case",
    "game_statistics",
    "results_statistics",
    "CaptureStats",
    "TimeSummary",
    "GAME_FIELDS",
    "SEEDING",
]
