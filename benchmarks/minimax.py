"""The minimax planner against the intruders that adapt, beside receding_horizon (docs/model.md section 7).

Each planner plays the same seeded episodes (seeds 1000..1019 by default) of each scenario against:
  drift           the config's drift law (what every planner assumes);
  fewest_ahead, least_defended, split_away
                  the registered heuristic intruders, as followers (they see the defenders' move);
  myopic          the follower's one-step best response: each step, of every pure routing of the
                  intruders' cells, the one whose engagements eliminate the least this step
                  (enumerated, when a state has at most --max-routings of them);
  lookahead       the follower looking two steps ahead: each step, the pure routing minimising this
                  step's eliminated mass plus the least the next step's routings leave to the
                  allocator's actual reply (maps whose intruders have at most --max-lookahead
                  pure routings a step);
  exact           the follower's best response over the whole episode: an exhaustive search over
                  the intruders' pure routings at every step, the allocator asked at every node (on
                  3x3 maps only: its tree grows as the routings' number to the power of the steps).
Printed per scenario: the mean intruder mass eliminated against each, the worst of the followers,
and the planner's median and mean CPU ms per predict() against drift (one thread).
--robustness R [R ...] adds minimax rows at those robustness values (the trade-off it traces).
Usage: python benchmarks/minimax.py --store /tmp/swarm-farm-planners.sqlite [--scenarios ...]
                                    [--episodes 20] [--robustness 0 0.5 1] [--skip-exact]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")
# benchmarks/farm.py would shadow the farm package: drop this folder from the path.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

SCENARIOS = ("outnumbered_3x3", "paper_3x3_c1_1.5", "outnumbered_5x5", "wide_front_8x8")
HEURISTICS = ("fewest_ahead", "least_defended", "split_away")


def pure_routings(n: int, I: np.ndarray, min_mass: float, budget: int):
    """(up, down): (K, N^2) float64 every pure routing of the cells of I: (N^2,) float64 holding mass
    outside column 0 (straight first), or None when K > budget."""
    cells = np.flatnonzero((I > min_mass) & (np.arange(n * n) % n > 0))
    options = [[d for d in (0, -1, 1) if 0 <= c // n + d < n] for c in cells]
    if np.prod([len(o) for o in options], dtype=np.float64) > budget:
        return None
    if len(cells) == 0:
        return np.zeros((1, n * n)), np.zeros((1, n * n))
    choice = np.array(list(itertools.product(*options)), dtype=np.int64)
    up, down = np.zeros((len(choice), n * n)), np.zeros((len(choice), n * n))
    up[:, cells], down[:, cells] = choice == -1, choice == 1
    return up, down


class Myopic:
    """The follower's one-step best response (an intruder policy, registered as `myopic` by main)."""

    budget = 4096
    client = None

    def __init__(self, config):
        from farm.alloc.game.dynamics import Layout
        from farm.alloc.game.model import EngagementModel

        self.config, self.layout = config, Layout(config.grid_size)
        self.model = EngagementModel(config, Myopic.client, False)

    @classmethod
    def make(cls, config):
        """The registry's maker."""
        return cls(config)

    def resolved(self, D, I):
        """(every pure routing of one episode's intruders I: (n2,), the step resolved under each against
        the defenders D: (n2,)), or None when there are more than the budget."""
        from farm.alloc.game.dynamics import resolve

        routes = pure_routings(self.config.grid_size, I, self.config.engage_min_mass, Myopic.budget)
        if routes is None:
            return None
        K = len(routes[0])
        return routes, resolve(self.layout, self.config, self.model, np.repeat(D[None], K, 0),
                               np.repeat(I[None], K, 0), routes)

    def routing(self, D, I):
        """Each episode's pure routing that eliminates the least this step (straight when none is enumerable)."""
        D, I = np.atleast_2d(D), np.atleast_2d(I)
        up, down = np.zeros(I.shape), np.zeros(I.shape)
        for b in range(len(I)):
            found = self.resolved(D[b], I[b])
            if found is None:
                continue
            routes, r = found
            k = int(np.argmin(r.eliminated))  # the first of the least: straight on ties
            up[b], down[b] = routes[0][k], routes[1][k]
        return up, down


class Lookahead(Myopic):
    """The follower looking two steps ahead against the allocator itself (registered as `lookahead` by
    main, its allocator set before each play): of every pure routing, the one minimising this step's
    eliminated mass plus the least the next step's pure routings leave to the allocator's actual
    reply (the allocator asked at each routing's next state, the smallest first, while it can still
    be the least)."""

    allocator = None

    def routing(self, D, I):
        """Each episode's pure routing of the least two-step eliminated mass."""
        from farm.alloc.game.dynamics import move_defenders, move_probabilities, observe, resolve

        cfg, n = self.config, self.config.grid_size
        D, I = np.atleast_2d(D), np.atleast_2d(I)
        up, down = np.zeros(I.shape), np.zeros(I.shape)
        for b in range(len(I)):
            found = self.resolved(D[b], I[b])
            if found is None:
                continue
            routes, r = found
            best, pick = np.inf, 0
            for k in np.argsort(r.eliminated, kind="stable"):
                if r.eliminated[k] >= best:
                    break
                total = r.eliminated[k]
                nxt = pure_routings(n, r.I[k], cfg.engage_min_mass, Myopic.budget)
                if r.remaining[k] >= cfg.epsilon and nxt is not None:
                    action, _ = Lookahead.allocator.predict(observe(r.D[k][None], r.I[k][None])[0])
                    moved = move_defenders(self.layout, r.D[k][None],
                                           move_probabilities(self.layout, cfg, np.asarray(action)[None]))
                    J = len(nxt[0])
                    total += resolve(self.layout, cfg, self.model, np.repeat(moved, J, 0),
                                     np.repeat(r.I[k][None], J, 0), nxt).eliminated.min()
                if total < best:
                    best, pick = total, int(k)
            up[b], down[b] = routes[0][pick], routes[1][pick]
        return up, down


class Timed:
    """An allocator whose predict() CPU seconds are kept (cpu: list of float)."""

    def __init__(self, policy):
        self.policy, self.cpu = policy, []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        c0 = time.process_time()
        out = self.policy.predict(obs, state, episode_start, deterministic)
        self.cpu.append(time.process_time() - c0)
        return out


def exact_worst(config, client, policy, episodes: int, seed: int) -> np.ndarray:
    """(episodes,) float64: each episode's eliminated mass against the follower's exact best response
    (the minimum over the intruders' pure routings at every step, the allocator asked at each node)."""
    from gymnasium.utils import seeding

    from farm.alloc.game.dynamics import Layout, move_defenders, move_probabilities, observe, resolve, start_densities
    from farm.alloc.game.model import EngagementModel

    layout, model, n = Layout(config.grid_size), EngagementModel(config, client, False), config.grid_size

    def worst(D, I, steps):
        if I.sum() < config.epsilon or steps >= config.max_steps:
            return 0.0
        if not np.any((I > config.engage_min_mass) & (np.arange(n * n) % n > 0)):
            return 0.0  # all the mass in column 0: it breaches, nothing to engage
        routes = pure_routings(n, I, config.engage_min_mass, 10 ** 9)
        action, _ = policy.predict(observe(D[None], I[None])[0], deterministic=True)
        D1 = move_defenders(layout, D[None], move_probabilities(layout, config, np.asarray(action)[None]))
        K = len(routes[0])
        r = resolve(layout, config, model, np.repeat(D1, K, 0), np.repeat(I[None], K, 0), routes)
        best = np.inf
        for k in np.argsort(r.eliminated, kind="stable"):
            if r.eliminated[k] >= best:
                break  # what comes after is never negative
            later = 0.0 if r.remaining[k] < config.epsilon else worst(r.D[k], r.I[k], steps + 1)
            best = min(best, r.eliminated[k] + later)
        return best

    out = []
    for k in range(episodes):
        rng = seeding.np_random(seed + k)[0]
        D, I = start_densities(layout, rng.dirichlet(np.ones(n))[None])
        out.append(worst(D[0], I[0], 0))
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default="/tmp/swarm-farm-planners.sqlite", help="the capture-time store (warmed)")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--planners", nargs="+", default=["minimax", "receding_horizon"])
    ap.add_argument("--options", default="{}", help="minimax's options, JSON")
    ap.add_argument("--robustness", nargs="*", type=float, default=[], help="more minimax rows at these values")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--max-routings", type=int, default=4096, help="myopic's enumeration budget per state")
    ap.add_argument("--max-lookahead", type=int, default=200, help="lookahead on maps of at most this many routings")
    ap.add_argument("--skip-exact", action="store_true", help="no exhaustive search (it runs on 3x3 maps only)")
    a = ap.parse_args()
    from farm.alloc.allocators import make_allocator
    from farm.alloc.evaluation.rollout import play
    from farm.alloc.game.lattice import memo_client
    from farm.alloc.game.scenarios import SCENARIOS as ALL
    from farm.alloc.intruders import register_intruders

    options = json.loads(a.options)
    rows = [(name, name, options if name == "minimax" else {}) for name in a.planners]
    rows += [(f"minimax r={r:g}", "minimax", {**options, "robustness": r}) for r in a.robustness]
    configs = {s: ALL[s].config() for s in a.scenarios}
    client, pairs, t_warm = memo_client(configs.values(), "local", a.store)
    Myopic.client, Myopic.budget = client, a.max_routings
    register_intruders("myopic", Myopic.make, kind="heuristic", replace=True)
    register_intruders("lookahead", Lookahead.make, kind="heuristic", replace=True)
    print(f"store {a.store}: {len(pairs)} lattice pairs warm in {t_warm:.1f} s; {a.episodes} episodes each "
          f"(seeds {a.seed}..{a.seed + a.episodes - 1}); load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores")
    t0 = time.perf_counter()
    for scenario, config in configs.items():
        n = config.grid_size
        sides = ["drift", *HEURISTICS, "myopic"] + (["lookahead"] if 2 * 3 ** (n - 2) * 2 <= a.max_lookahead else [])
        sides += ["exact"] if n == 3 and not a.skip_exact else []
        print(f"\n{scenario}: eliminated mass, mean over episodes; worst: the least of the followers' columns; "
              "ms, mean ms: median and mean CPU ms per step against drift")
        print(f"{'planner':<22}" + "".join(f"{s:>16}" for s in sides) + f"{'worst':>10}{'ms':>8}{'mean ms':>9}")
        for label, name, opts in rows:
            means, ms, mean_ms = {}, None, None
            for side in sides:
                cfg = config if side in ("drift", "exact") else ALL[scenario].config(intruders=side)
                policy = Timed(make_allocator(name, cfg, client, **opts))
                Lookahead.allocator = make_allocator(name, cfg, client, **opts)
                if side == "exact":
                    means[side] = float(exact_worst(cfg, client, policy, a.episodes, a.seed).mean())
                    continue
                played = play(cfg, policy, client, a.episodes, a.seed)
                means[side] = float(np.mean([e.summary["eliminated"] for e in played]))
                if side == "drift":
                    ms, mean_ms = 1e3 * float(np.median(policy.cpu)), 1e3 * float(np.mean(policy.cpu))
            worst = min(v for s, v in means.items() if s != "drift")
            print(f"{label:<22}" + "".join(f"{means[s]:>16.3f}" for s in sides)
                  + f"{worst:>10.3f}{ms:>8.1f}{mean_ms:>9.1f}", flush=True)
    client.close()
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
