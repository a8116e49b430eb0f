"""The compiled engine against the numpy engine it replaced and the slow scipy
reference, on the same games, in one process, on one core.

For each case (team sizes, policies, batch size B) it prints ms per game of each
implementation, the ratios, whether the capture times agree, and how far the
compiled engine is from an estimate of this machine's limit: the arithmetic a
game-step needs at the least (a model, below) divided by the scalar
floating-point rate this same run measures on a tight compiled loop.

Work model per game-step, in flops: each live evader's cell is clipped by its
~6 Voronoi neighbours and tested against ~6 more candidates, each test 4 flops
on each of ~7 vertices, each clip ~20 flops, and its area, centroid and edges
take ~15 flops per vertex: about 12*7*4 + 6*20 + 7*15 = 560 flops a cell (0 when
no policy needs cells); the pursuer-evader distances 4 flops a pair; moves,
projection and policies ~15 flops an agent. Usage:
    python benchmarks/engine.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # the numpy engine lives with the tests

import numpy as np  # noqa: E402
import numpy_engine  # noqa: E402
from numba import njit  # noqa: E402
from shapely_reference import reference_game  # noqa: E402

from workers import Case, sample_initial_positions, simulate_games  # noqa: E402
from workers.policies import get_evader_policy, get_pursuer_policy  # noqa: E402

# label, n_p, n_e, pursuer policy, evader policy, batch B, reference games
CASES = [
    ("5v1 area_min/centroid", 5, 1, "area_min", "centroid", 1, 3),
    ("5v1 area_min/centroid", 5, 1, "area_min", "centroid", 16, 3),
    ("5v1 area_min/centroid", 5, 1, "area_min", "centroid", 2000, 3),
    ("5v1 pure_pursuit/target", 5, 1, "pure_pursuit", "target", 16, 3),
    ("20v10 area_min/centroid", 20, 10, "area_min", "centroid", 16, 1),
    ("100v50 area_min/centroid", 100, 50, "area_min", "centroid", 2, 1),
    ("100v100 area_min/centroid", 100, 100, "area_min", "centroid", 2, 0),
]
FLOPS_PER_CELL, FLOPS_PER_PAIR, FLOPS_PER_AGENT = 560, 4, 15


@njit(cache=True)
def _scalar_kernel(x, y, n):
    """Half-plane tests of a 7-vertex polygon, the clipper's inner loop: 4 flops a vertex."""
    acc = 0.0
    for r in range(n):
        nx, ny, c = 0.6 + 1e-9 * r, 0.8, 0.5
        for v in range(7):
            acc += (x[v] - c) * nx + (y[v] - c) * ny
    return acc


def scalar_flops_per_second() -> float:
    x, y = np.random.default_rng(0).random(7), np.random.default_rng(1).random(7)
    _scalar_kernel(x, y, 10)
    n = 2_000_000
    t0 = time.perf_counter()
    _scalar_kernel(x, y, n)
    return n * 7 * 4 / (time.perf_counter() - t0)


def model_flops(n_p: int, n_e_live: np.ndarray, cells: bool) -> float:
    """Minimal flops of one game-step with n_e_live live evaders (mean over steps)."""
    return (FLOPS_PER_CELL * n_e_live * cells + FLOPS_PER_PAIR * n_p * n_e_live + FLOPS_PER_AGENT * (n_p + n_e_live))


def timed(fn, repeat: int = 1) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller batches, no reference for the big games")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    rate = scalar_flops_per_second()
    print(f"scalar rate of this core on the clipper's inner loop: {rate / 1e9:.2f} Gflop/s")
    head = (f"{'case':<27}{'B':>5}{'compiled':>10}{'numpy':>9}{'reference':>11}{'vs ref':>8}{'vs numpy':>9}"
            f"{'same t_c':>9}{'us/step':>9}{'limit':>8}")
    print(head + "\n" + f"{'':<32}{'ms/game':>10}{'ms/game':>9}{'ms/game':>11}")
    for label, n_p, n_e, pp, ep, batch, n_ref in CASES:
        if a.quick:
            batch, n_ref = min(batch, 64), (n_ref if n_p <= 5 else 0)
        case = Case(n_p, n_e, pursuer_policy=pp, evader_policy=ep)
        P, E = sample_initial_positions(case, a.seed, 0, batch)
        kw = dict(pursuer_policy=pp, evader_policy=ep)
        if batch == 1:  # a single game per call: the B = 1 cost, over a few games
            n_single = 20
            P, E = sample_initial_positions(case, a.seed, 0, n_single)
            def singles(simulate, P=P, E=E, kw=kw, n=n_single):
                return [simulate(P[g:g + 1], E[g:g + 1], **kw) for g in range(n)]

            t = timed(lambda: singles(simulate_games), 3) / n_single
            t_np = timed(lambda: singles(numpy_engine.simulate_games)) / n_single
            res = simulate_games(P, E, **kw)
        else:
            t = timed(lambda P=P, E=E, kw=kw: simulate_games(P, E, **kw), 3 if batch <= 64 else 1) / batch
            t_np = timed(lambda P=P, E=E, kw=kw: numpy_engine.simulate_games(P, E, **kw)) / batch
            res = simulate_games(P, E, **kw)
        ours = res.capture_times
        theirs = numpy_engine.simulate_games(P[: max(n_ref, 1)], E[: max(n_ref, 1)], **kw).capture_times
        if n_ref:
            t0 = time.perf_counter()
            ref = np.array([reference_game(P[g], E[g], **kw) for g in range(n_ref)])
            t_ref = (time.perf_counter() - t0) / n_ref
            same = np.mean((ours[:n_ref] == ref) | (np.isnan(ours[:n_ref]) & np.isnan(ref)))
            ref_cols = f"{1e3 * t_ref:>11.1f}{t_ref / t:>7.0f}x"
        else:
            same = np.mean((ours[:1] == theirs) | (np.isnan(ours[:1]) & np.isnan(theirs)))
            ref_cols = f"{'-':>11}{'-':>8}"
        steps = res.steps.sum()
        live = (np.where(res.capture_step >= 0, res.capture_step, res.steps[:, None])).sum() / max(steps, 1)
        cells = get_pursuer_policy(pp).needs_cells or get_evader_policy(ep).needs_cells
        limit = model_flops(n_p, live, cells) / rate  # seconds a game-step needs at the least
        per_step = t * len(res.steps) / steps
        print(f"{label:<27}{batch:>5}{1e3 * t:>10.3f}{1e3 * t_np:>9.2f}{ref_cols}{t_np / t:>8.0f}x"
              f"{same:>9.0%}{1e6 * per_step:>9.2f}{per_step / limit:>7.1f}x", flush=True)
    print("same t_c: capture times equal to the reference's (numpy engine's where no reference ran);")
    print("limit: the compiled engine's time per game-step over the work model's minimum at the measured rate.")


if __name__ == "__main__":
    main()
