"""The planners' cost per step and what they achieve, beside the baselines (docs/model.md section 7).

1. cost: median CPU ms per predict() of each planner and baseline over the steps of a few
   seeded episodes, side by side in one process pinned to one core (numerical libraries at
   one thread), warm store (every lattice pair in the client's memo), against the budget
   per step: 50 ms on 3x3 (100 v 50), 1 s on 8x8 (800 v 400), both `team_sizes: lattice`.
   CPU time, not wall time, is the measure because a shared machine's other work lengthens
   wall time by whatever it takes (the median wall ms is printed beside it).
2. outcome: 10 seeded episodes (seeds 1000..1009) of each with
   farm.alloc.evaluation.rollout.evaluate_policies on paper_3x3_c1_1.5 and larger_8x8: intruder mass
   eliminated and return, each with its 95% t interval. `intercept/largest` is intercept
   sending a cell's mass to the largest of the intruder cells it meets earliest (the
   default, `split`, shares it in proportion to their mass).
The store is warmed first over each scenario's lattice (client.warm: 256 pairs on 8x8,
the 256 v 256 games the slow ones, a few minutes on 2 cores with --mode ray).
Usage: python benchmarks/planners.py [--store /tmp/swarm-farm-planners.sqlite] [--mode local|ray]
                                     [--timing-episodes 3] [--episodes 10]   (a few minutes, warm store)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")
# benchmarks/farm.py would shadow the farm package: drop this folder from the path.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

BUDGET_MS = {"paper_3x3_c1_1.5": 50.0, "larger_8x8": 1000.0}


def policies(config, client):
    """Every baseline and planner of config, by name, and intercept with the tie rule it replaced."""
    from farm.alloc.allocators import allocator_names, make_allocator

    return {**{name: make_allocator(name, config, client) for name in allocator_names(("baseline", "planner"))},
            "intercept/largest": make_allocator("intercept", config, client, ties="largest")}


def cost(config, client, episodes: int) -> dict:
    """{policy: (median CPU ms, 90th percentile CPU ms, median wall ms)} of predict() over the steps of
    episodes seeded 1000.. (one untimed call first: imports and the planner's table of statistics).

    CPU time (time.process_time, this process only, one thread) is what a step costs on one
    core whatever else the machine runs; wall time is beside it for reference.
    """
    from farm.alloc import SwarmAllocationEnv

    out = {}
    for name, policy in policies(config, client).items():
        env = SwarmAllocationEnv(config, client=client)
        policy.predict(env.reset(seed=0)[0])
        cpu, wall = [], []
        for seed in range(1000, 1000 + episodes):
            obs, _ = env.reset(seed=seed)
            while True:
                c0, t0 = time.process_time(), time.perf_counter()
                action, _ = policy.predict(obs, deterministic=True)
                cpu.append(time.process_time() - c0)
                wall.append(time.perf_counter() - t0)
                obs, _, term, trunc, _ = env.step(action)
                if term or trunc:
                    break
        out[name] = (1e3 * float(np.median(cpu)), 1e3 * float(np.percentile(cpu, 90)), 1e3 * float(np.median(wall)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default="/tmp/swarm-farm-planners.sqlite", help="the capture-time store (warmed)")
    ap.add_argument("--mode", choices=["local", "ray"], default="local", help="warm in process or on a local Ray")
    ap.add_argument("--timing-episodes", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=10, help="evaluation episodes, seeded 1000..")
    a = ap.parse_args()
    from farm.alloc.evaluation.rollout import evaluate_policies
    from farm.alloc.game.lattice import memo_client
    from farm.alloc.game.scenarios import SCENARIOS

    names = list(BUDGET_MS)
    configs = {name: SCENARIOS[name].config() for name in names}
    client, pairs, t_warm = memo_client(configs.values(), a.mode, a.store)  # every lattice pair in its memo
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core from here on
    print(f"store {a.store}: {len(pairs)} lattice pairs warm ({a.mode}) in {t_warm:.1f} s; timing on one core "
          f"(load average {os.getloadavg()[0]:.1f} over {os.cpu_count()} cores: other work slows every row alike)")

    t0 = time.perf_counter()
    costs = {name: cost(configs[name], client, a.timing_episodes) for name in names}
    t_cost = time.perf_counter() - t0
    print(f"\ncost per step: CPU ms per predict(), median and 90th percentile over the steps of "
          f"{a.timing_episodes} episodes (seeds 1000..), its ratio to the budget, and the median wall ms")
    print(f"{'':<18}" + "".join(f"{name:>37}" for name in names))
    print(f"{'policy':<18}" + f"{'cpu ms':>10}{'p90':>8}{'/budget':>9}{'wall ms':>10}" * len(names))
    for policy in costs[names[0]]:
        row = f"{policy:<18}"
        for name in names:
            med, p90, wall = costs[name][policy]
            row += f"{med:>10.2f}{p90:>8.1f}{med / BUDGET_MS[name]:>9.3f}{wall:>10.2f}"
        print(row)
    print("budget per step: " + ", ".join(f"{name} {BUDGET_MS[name]:g} ms" for name in names))

    t0 = time.perf_counter()
    for name in names:
        table, _, _ = evaluate_policies(configs[name], policies(configs[name], client), client, a.episodes, 1000)
        print(f"\n{name}: {a.episodes} episodes (seeds 1000..{999 + a.episodes}), mean and 95% CI")
        print(f"{'policy':<18}{'eliminated':>18}{'return':>20}{'breached':>18}")
        for _, r in table.iterrows():
            print(f"{r['policy']:<18}{r['eliminated_mean']:>10.3f} ± {r['eliminated_ci95']:<5.3f}"
                  f"{r['return_mean']:>12.3f} ± {r['return_ci95']:<5.3f}{r['breached_mean']:>10.3f} ± "
                  f"{r['breached_ci95']:<5.3f}")
    client.close()
    print(f"\ncost {t_cost:.1f} s, evaluation {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
