"""swarm-farm's data plane: pursuit-evasion kernels in numpy and numba (no Ray, no torch).

    from workers import simulate_games
    res = simulate_games(pursuers, evaders, pursuer_policy="area_min", evader_policy="centroid")
    res.capture_times  # (B, n_e) float64, NaN where not captured
    res.escape_times   # (B, n_e) float64, NaN where not escaped (only with exit_point=(x, y))

The modules, each importing only those above it (no cycle):
errors, version, arena, compiled (the kernels' cache folder), geometry (Voronoi cells),
policies (one file per policy, the registry and its generated dispatch), case (the game
model: Case, InitialLaw, defaults), engine (the compiled games), stats (per-game and
per-case statistics), montecarlo (seeded initial positions, run_case).
"""

from workers.arena import DEFAULT_ARENA, Arena, make_arena
from workers.compiled import kernel_cache
from workers.errors import CoarseStepWarning, InputError, SwarmFarmError
from workers.version import ENGINE_VERSION

with kernel_cache():  # every compiled kernel is defined in these modules
    from workers.engine import GameResults, simulate_games
    from workers.geometry import Cells, voronoi_cells
    from workers.policies import EVADER_POLICIES, PURSUER_POLICIES

from workers.case import GAME_FIELDS, PAPER_LAW, Case, InitialLaw, case_defaults  # noqa: E402
from workers.montecarlo import SEEDING, run_case, run_games, sample_initial_positions, simulate_case  # noqa: E402
from workers.stats import CaptureStats, TimeSummary, game_statistics, results_statistics  # noqa: E402

__all__ = [
    "simulate_games",
    "GameResults",
    "ENGINE_VERSION",
    "InputError",
    "SwarmFarmError",
    "CoarseStepWarning",
    "Arena",
    "DEFAULT_ARENA",
    "make_arena",
    "Cells",
    "voronoi_cells",
    "PURSUER_POLICIES",
    "EVADER_POLICIES",
    "Case",
    "InitialLaw",
    "PAPER_LAW",
    "case_defaults",
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
