"""The farm's overhead and scaling: one 40,000-game sweep run three ways in one process.

1. in-process: the same shards simulated directly, no Ray, no files (pure compute);
2. Ray, 1 worker; 3. Ray, 2 workers (a real single-node Ray with 2 CPUs, started once,
   warmed up with a tiny sweep so worker start-up is not counted).
Prints wall times, the farm's overhead over in-process and the 2-worker speed-up.
Shards have the farm's default size (about half a second of work by the engine's cost model).
Targets: overhead <= 10 %, 2 workers >= 1.8x one. Usage: python benchmarks/farm.py [--games N]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

# This file is named farm.py: keep its folder from shadowing the farm package.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import yaml  # noqa: E402

from farm.games.sweep import (  # noqa: E402
    SweepConfig,  # noqa: E402
    SweepRun,
    run_sweep,
    simulate_shard,
)
from farm.runtime import ray_cluster  # noqa: E402


def make_config(games: int, name: str = "bench") -> SweepConfig:
    return SweepConfig(**yaml.safe_load(f"""
name: {name}
seed: 11
games_per_point: {games // 2}
base: {{n_pursuers: 5, n_evaders: 1, pursuer_policy: area_min, evader_policy: centroid}}
vary: {{grid: {{evader_policy: [centroid, constant_area]}}}}
"""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--games", type=int, default=40_000)
    a = ap.parse_args()
    config = make_config(a.games)
    run = SweepRun(config, "/nonexistent")
    shards = run.all_shards()

    t0 = time.perf_counter()
    for shard in shards:
        simulate_shard(run.points[shard.point].case, config.seed, shard)
    t_direct = time.perf_counter() - t0

    t0 = time.perf_counter()
    with ray_cluster(num_cpus=2, dashboard=False), tempfile.TemporaryDirectory() as tmp:
        t_start = time.perf_counter() - t0
        run_sweep(make_config(40, "warm-up"), Path(tmp) / "warm", workers=2, show_progress=False)
        times = {}
        for workers in (1, 2):
            t0 = time.perf_counter()
            _, info = run_sweep(config, Path(tmp) / f"w{workers}", workers=workers, show_progress=False)
            times[workers] = time.perf_counter() - t0
            assert info["done"] == len(shards)

    print(f"{a.games} games of 5v1 area_min in {len(shards)} shards of {shards[0].games}; "
          f"Ray start-up {t_start:.1f} s (not counted)")
    print(f"{'run':<22}{'wall s':>8}{'games/s':>10}{'vs in-process':>15}")
    print(f"{'in-process, 1 core':<22}{t_direct:>8.1f}{a.games / t_direct:>10.0f}{'1.00x':>15}")
    for w in (1, 2):
        print(f"{f'Ray, {w} worker(s)':<22}{times[w]:>8.1f}{a.games / times[w]:>10.0f}{t_direct / times[w]:>14.2f}x")
    print(f"farm overhead (1 worker vs in-process): {100 * (times[1] / t_direct - 1):+.1f} %  (target <= 10 %)")
    print(f"2 workers vs 1: {times[1] / times[2]:.2f}x  (target >= 1.8x)")


if __name__ == "__main__":
    main()
