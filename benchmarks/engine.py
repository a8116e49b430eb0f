"""Engine vs the slow reference, same games, one process, one core.

Prints games/s of both and their ratio for the paper cases (1, 3, 5 pursuers vs
1 evader, area_min vs centroid/constant_area) and for 20v10 and 100v50 games.
The engine plays its games as one batch (that is its point); the reference plays
the first few of the same games one at a time. Usage:
    python benchmarks/engine.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from workers import Case, run_games, sample_initial_positions  # noqa: E402
from workers.reference import reference_game  # noqa: E402

# name, n_p, n_e, evader policy, engine games, reference games
CASES = [
    ("1v1 area_min/constant_area", 1, 1, "constant_area", 2000, 8),
    ("3v1 area_min/centroid", 3, 1, "centroid", 2000, 6),
    ("5v1 area_min/centroid", 5, 1, "centroid", 2000, 6),
    ("20v10 area_min/centroid", 20, 10, "centroid", 16, 2),
    ("100v50 area_min/centroid", 100, 50, "centroid", 3, 1),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a tenth of the games (smoke run)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    print(f"{'case':<28}{'engine g/s':>12}{'ref g/s':>10}{'ratio':>9}{'engine s/game':>15}{'same t_c':>10}")
    for name, n_p, n_e, ep, n_engine, n_ref in CASES:
        if a.quick:
            n_engine = max(1, n_engine // 10)
        case = Case(n_p, n_e, pursuer_policy="area_min", evader_policy=ep)
        t0 = time.perf_counter()
        res = run_games(case, a.seed, 0, n_engine)
        t_engine = time.perf_counter() - t0
        p, e = sample_initial_positions(case, a.seed, 0, n_ref)
        t0 = time.perf_counter()
        ref = np.array([reference_game(p[b], e[b], pursuer_policy="area_min", evader_policy=ep) for b in range(n_ref)])
        t_ref = time.perf_counter() - t0
        ours = res.capture_times[:n_ref]
        same = np.mean((ours == ref) | (np.isnan(ours) & np.isnan(ref)))
        g_engine, g_ref = n_engine / t_engine, n_ref / t_ref
        print(
            f"{name:<28}{g_engine:>12.1f}{g_ref:>10.2f}{g_engine / g_ref:>8.0f}x"
            f"{t_engine / n_engine:>15.4f}{same:>10.0%}",
            flush=True,
        )
    # A single 100v50 game alone (no batching help): the "under 1 s" target.
    case = Case(100, 50)
    times = []
    for g in range(3):
        t0 = time.perf_counter()
        run_games(case, a.seed, g, g + 1)
        times.append(time.perf_counter() - t0)
    print(f"single 100v50 game: {', '.join(f'{t:.2f}' for t in times)} s (target < 1 s)")


if __name__ == "__main__":
    main()
