"""Capture-time service latencies and fill time, one process.

1. client hit latency (memo, no Ray round trip)      target <= 20 us
2. actor round trip for a batch of 9 cached keys    target <= 3 ms
3. time to fill a 10 x 10 (n_p, n_e) table at 64 games per case, area_min vs
   centroid, on a local Ray with 2 workers (misses computed on the farm).
Usage: python benchmarks/service.py [--size 10] [--games 64]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

# benchmarks/farm.py would shadow the farm package: drop this folder from the path.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

from farm.runtime import ray_cluster  # noqa: E402
from farm.service import CaptureTimeClient, GameSettings, get_service  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=10)
    ap.add_argument("--games", type=int, default=64)
    a = ap.parse_args()
    settings = GameSettings.of(games=a.games)
    with tempfile.TemporaryDirectory() as tmp, ray_cluster(num_cpus=2, dashboard=False) as ray:
        service = get_service(Path(tmp) / "bench.sqlite", name="bench-service")
        client = CaptureTimeClient(settings, service=service)
        pairs = [(p, e) for p in range(1, a.size + 1) for e in range(1, a.size + 1)]
        t0 = time.perf_counter()
        client.warm(pairs)
        t_fill = time.perf_counter() - t0
        stats = client.stats()

        client.get_many(pairs)  # warm the memo
        n = 200_000
        t0 = time.perf_counter()
        for i in range(n):
            client.get(*pairs[i % 9])
        hit_us = (time.perf_counter() - t0) / n * 1e6

        batch = [settings.key(*pr) for pr in pairs[:9]]
        ray.get(service.get_many.remote(batch))
        rtts = []
        for _ in range(300):
            t0 = time.perf_counter()
            ray.get(service.get_many.remote(batch))
            rtts.append((time.perf_counter() - t0) * 1e3)
    print(f"{'measure':<48}{'value':>12}{'target':>10}")
    print(f"{'client hit latency (memo)':<48}{hit_us:>10.2f}us{'<= 20us':>10}")
    print(f"{'actor round trip, batch of 9 cached keys (median)':<48}{statistics.median(rtts):>10.2f}ms{'<= 3ms':>10}")
    print(f"{'  same, 95th percentile':<48}{sorted(rtts)[int(0.95 * len(rtts))]:>10.2f}ms")
    print(f"{f'fill {a.size}x{a.size} table, {a.games} games/case, 2 workers':<48}{t_fill:>11.1f}s"
          f"{'':>10}  ({len(stats['computations'])} cases computed, {len(pairs) * a.games / t_fill:.0f} games/s)")


if __name__ == "__main__":
    main()
