"""The search intruders' cost: an episode against `search` intruders beside one exact search of it.

Each allocator plays the same seeded episodes (seeds 2000.. by default) of each 3 x 3 scenario:
  drift    play() against the drift law: the allocator's own planning, once a step;
  exact    farm.alloc.intruders.exact_search.exact_response against the allocator: one search an episode
           (the allocator asked at every state of the intruders' tree);
  search   play() against `search` intruders modelling that allocator alone: the same routings
           (checked episode by episode), re-planned at every step from the episode's memos;
  search2  play() against `search` intruders modelling it and --second (uniform weights).
Printed: CPU seconds an episode of each, search / (exact + drift) (the memos' promise: an episode's
re-planning costs one search; the target is at most 1.5) and search2 / search.
Usage: python benchmarks/searching.py --store PATH [--scenarios ...] [--allocators ...] [--episodes 5]
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

TARGET = 1.5  # search / (exact + drift) at most


def cpu(f, *args):
    """(f(*args), the CPU seconds of this process it took)."""
    c0 = time.process_time()
    out = f(*args)
    return out, time.process_time() - c0


def measure(config, name: str, second: str, client, episodes: int, seed: int) -> dict:
    """One row: the CPU seconds of drift, exact, search and search2 over the episodes, and whether
    search played exact's routings (the same eliminated mass, episode by episode)."""
    from farm.alloc.allocators import make_allocator
    from farm.alloc.evaluation.rollout import play
    from farm.alloc.intruders.exact_search import exact_response

    def played(env):
        return play(env, make_allocator(name, env, client), client, episodes, seed)

    def searched(policy):
        return [exact_response(config, policy, client, seed + k) for k in range(episodes)]

    def against(members):
        return config.model_copy(update={"intruders": "search", "intruder_options": {"allocators": members}})

    _, drift = cpu(played, config)
    exact, t_exact = cpu(searched, make_allocator(name, config, client))
    one, search = cpu(played, against([name]))
    _, search2 = cpu(played, against([name, second]))
    same = bool(np.array_equal([e.summary["eliminated"] for e in one], [r.summary["eliminated"] for r in exact]))
    return {"drift": drift, "exact": t_exact, "search": search, "search2": search2, "same": same}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default="/tmp/swarm-farm-planners.sqlite", help="the capture-time store")
    ap.add_argument("--scenarios", nargs="+", default=["outnumbered_3x3", "paper_3x3_c1_1.5"])
    ap.add_argument("--allocators", nargs="+", default=["intercept", "receding_horizon", "minimax"])
    ap.add_argument("--second", default="transport", help="search2's second member")
    ap.add_argument("--episodes", type=int, default=5)
    ap.add_argument("--seed", type=int, default=2000)
    a = ap.parse_args()
    from farm.alloc.game.lattice import memo_client
    from farm.alloc.game.scenarios import SCENARIOS

    configs = {s: SCENARIOS[s].config() for s in a.scenarios}
    client, pairs, t_warm = memo_client(configs.values(), "local", a.store)
    print(f"store {a.store}: {len(pairs)} lattice pairs warm in {t_warm:.1f} s; {a.episodes} episodes each "
          f"(seeds {a.seed}..{a.seed + a.episodes - 1}); load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} "
          f"cores; CPU seconds an episode")
    print(f"{'scenario':<18}{'allocator':<18}{'drift':>8}{'exact':>8}{'search':>8}{'search2':>9}"
          f"{'search/(exact+drift)':>22}{'search2/search':>16}{'same play':>11}")
    met = True
    for scenario, config in configs.items():
        for name in a.allocators:
            r, n = measure(config, name, a.second, client, a.episodes, a.seed), a.episodes
            ratio = r["search"] / (r["exact"] + r["drift"])
            met &= r["same"] and ratio <= TARGET
            print(f"{scenario:<18}{name:<18}{r['drift'] / n:>8.2f}{r['exact'] / n:>8.2f}{r['search'] / n:>8.2f}"
                  f"{r['search2'] / n:>9.2f}{ratio:>22.2f}{r['search2'] / r['search']:>16.2f}"
                  f"{'yes' if r['same'] else 'NO':>11}", flush=True)
    client.close()
    print(f"\ntarget (search / (exact + drift) <= {TARGET}, the same play): {'met' if met else 'NOT met'}")


if __name__ == "__main__":
    main()
