"""`farm robust` (farm.studies.robust.run_robust): one iteration on 2 workers against 1.

One iteration of policy-space response oracles on outnumbered_3x3 (the planners and
spread_evenly against drift and the heuristic intruders): its payoff rollouts (every pair, then
the responses' pairs) and its best-response trainings (the defenders' DAgger-started from
intercept, the intruders', --steps PPO steps each, --responses seeds a side, the one gaining
most kept), run with workers=1 (one task or trial at a time) and with workers=2, each into its
own folder, on one local 2-CPU Ray started here and one capture-time store warmed first (no
timed run computes a game). With 2 workers two trials train side by side; with one response a
side the intruders' trial also has the allocators' moves answered by two processes
(opponent_procs). An untimed short run first starts Ray's worker processes; then 1 and 2 workers
are timed in turn, --repeats times each, and each one's fastest run is compared. Each run prints
its trials' seconds and the cores busy on average (the whole machine's CPU time over the run's).
Target: 2 workers at least 1.8x as fast as 1. Every run must give the same iteration
(populations, mixtures, payoffs).
First, the part of an iteration that the second process speeds: the intruders' batched env (8
episodes, pure routes drawn at random) against receding_horizon, its steps per second with the
allocator's moves answered by 1 process and by 2 (opponent_procs), in turn, the best of --repeats
windows of --seconds each.
Beside them, the machine's own ceiling with Ray's processes running: the same CPU-bound work (small
matrix products and a Python loop, no Ray) done by one process and by two side by side, the best of
--repeats; two trials side by side cannot scale better than this (--ceiling-only measures it alone).
Usage: python benchmarks/robust.py [--steps 20000] [--episodes 20] [--responses 2] [--repeats 2] [--seconds 10]
                                  [--skip-env] [--ceiling-only]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

# benchmarks/farm.py would shadow the farm package: drop this folder from the path.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

TARGET = 1.8


def config(store: Path, steps: int, episodes: int, responses: int = 1):
    """One iteration's RobustConfig: `steps` PPO steps a best response, `responses` of them a side,
    `episodes` a payoff."""
    from farm.studies.robust import RobustConfig

    ppo = {"algo": "ppo", "ppo.n_timesteps": steps, "ppo.n_steps": 128, "ppo.batch_size": 256, "n_envs": 8,
           "eval.freq": steps, "eval.episodes": 5}
    return RobustConfig(name="bench", scenario="outnumbered_3x3", iterations=1, distill=None,
                        allocators=["intercept", "mmr", "receding_horizon", "transport", "spread_evenly"],
                        intruders=["drift", "fewest_ahead", "least_defended", "split_away"],
                        payoffs={"episodes": episodes}, responses=responses,
                        training={"defenders": {**ppo, "pretrain": {"expert": "intercept", "iterations": 1,
                                                                    "episodes": 16}, "repair": "levels"},
                                  "intruders": ppo},
                        store=str(store))


def busy_work(rounds: int) -> float:
    """CPU-bound work (rounds of a 64 x 64 matrix product and a short Python loop); its seconds."""
    import numpy as np

    t0 = time.perf_counter()
    a = np.random.default_rng(0).random((64, 64))
    for _ in range(rounds):
        b = a @ a
        a = b / b.max()
        total = 0
        for j in range(300):
            total += j * j
    return time.perf_counter() - t0


def ceiling(repeats: int, rounds: int = 200_000) -> float:
    """The best over repeats of (one process's seconds for the work twice over) / (two processes'
    seconds side by side, one each): the speed-up two workers could reach on this machine."""
    import multiprocessing

    best = 0.0
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        pool.map(busy_work, [1000, 1000])  # both processes started
        for _ in range(repeats):
            t0 = time.perf_counter()
            pool.apply(busy_work, (2 * rounds,))
            one = time.perf_counter() - t0
            t0 = time.perf_counter()
            pool.map(busy_work, [rounds, rounds], chunksize=1)
            two = time.perf_counter() - t0
            print(f"machine ceiling: one process {one:.1f} s, two side by side {two:.1f} s: {one / two:.2f}x",
                  flush=True)
            best = max(best, one / two)
    return best


def env_steps(client, cfg, repeats: int, seconds: float) -> dict:
    """{procs: the best steps/s over repeats windows} of the intruders' env against receding_horizon."""
    import numpy as np

    from farm.alloc.envs.intruders import SwarmIntruderVectorEnv

    best = {1: 0.0, 2: 0.0}
    for _ in range(repeats):
        for procs in (1, 2):
            env = SwarmIntruderVectorEnv(cfg.alloc_config(), num_envs=8, opponent="receding_horizon",
                                         actions="pure", client=client, opponent_procs=procs)
            try:
                rng = np.random.default_rng(0)
                env.reset(seed=0)
                for _ in range(10):  # the helpers' first moves (their imports) untimed
                    env.step(rng.integers(0, 2, size=env.action_space.shape))
                n, t0 = 0, time.perf_counter()
                while time.perf_counter() - t0 < seconds:
                    env.step(rng.integers(0, 2, size=env.action_space.shape))
                    n += env.num_envs
                best[procs] = max(best[procs], n / (time.perf_counter() - t0))
            finally:
                env.close()
            print(f"intruders' env, opponent_procs={procs}: {n / (time.perf_counter() - t0):.0f} steps/s", flush=True)
    return best


def busy_seconds() -> float:
    """CPU seconds this machine has spent busy (all cores, every process) since boot."""
    import psutil

    t = psutil.cpu_times()
    return sum(t) - t.idle - getattr(t, "iowait", 0.0)


def trial_seconds(out: Path) -> list[tuple[str, float]]:
    """[(trial, its training's and evaluation's seconds)] of iteration 0's best responses in out."""
    import json

    return [(f.parent.name, (r := json.loads(f.read_text()))["train_seconds"] + r["evaluate_seconds"])
            for f in sorted((out / "iterations" / "0" / "trials").glob("*/result.json"))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000, help="PPO steps of each best response")
    parser.add_argument("--episodes", type=int, default=20, help="episodes of each payoff")
    parser.add_argument("--responses", type=int, default=2, help="best responses trained a side")
    parser.add_argument("--repeats", type=int, default=2, help="timed runs of each number of workers")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of each env window")
    parser.add_argument("--skip-env", action="store_true", help="skip the env's steps per second")
    parser.add_argument("--ceiling-only", action="store_true", help="measure the machine's ceiling alone")
    args = parser.parse_args()

    from farm.alloc.game.lattice import lattice_groups, warm_lattices
    from farm.runtime import ray_cluster
    from farm.service.client import open_client
    from farm.studies.robust import run_robust

    with tempfile.TemporaryDirectory(prefix="bench-robust-") as tmp, ray_cluster(num_cpus=2):
        tmp = Path(tmp)
        store = tmp / "store.sqlite"
        cfg = config(store, args.steps, args.episodes, args.responses)
        top = ceiling(args.repeats)
        if args.ceiling_only:
            print(f"the machine's ceiling (two processes over one, with Ray running): {top:.2f}x")
            return 0
        with open_client(cfg.alloc_config().game_settings(), mode="ray", store=store) as client:
            warm_lattices(client, lattice_groups([cfg.alloc_config()]), show_progress=False)
            if not args.skip_env:
                best = env_steps(client, cfg, args.repeats, args.seconds)
                print(f"intruders' env against receding_horizon: {best[1]:.0f} steps/s on 1 process, "
                      f"{best[2]:.0f} on 2: {best[2] / best[1]:.2f}x")
            warm = config(store, min(args.steps, 1024), args.episodes, args.responses)  # Ray's workers started
            run_robust(warm, tmp / "warm-up", workers=2, show_progress=False)
            seconds, states = {1: [], 2: []}, []
            for k in range(args.repeats):
                for workers in (1, 2):
                    t0, busy0 = time.perf_counter(), busy_seconds()
                    iterations, _ = run_robust(cfg, tmp / f"w{workers}-{k}", workers=workers, show_progress=False)
                    seconds[workers].append(time.perf_counter() - t0)
                    busy = (busy_seconds() - busy0) / seconds[workers][-1]
                    it = iterations[0]
                    states.append((it.row, it.column, it.value, it.gains))
                    trials = trial_seconds(tmp / f"w{workers}-{k}")
                    print(f"workers={workers}: {seconds[workers][-1]:.1f} s (value {it.value:.4f}, NashConv "
                          f"{it.nash_conv:.4f}); cores busy on average {busy:.2f}; trials "
                          + ", ".join(f"{name} {s:.1f} s" for name, s in trials), flush=True)
    same = all(s == states[0] for s in states)
    ratio = min(seconds[1]) / min(seconds[2])
    print(f"speed-up of 2 workers over 1: {ratio:.2f}x (target >= {TARGET}; the machine's ceiling {top:.2f}x); "
          f"the same iteration: {same}")
    return 0 if ratio >= TARGET and same else 1


if __name__ == "__main__":
    sys.exit(main())
