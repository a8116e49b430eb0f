"""`farm experiments` (farm.studies.experiments.run_experiment): trials side by side, and one service for all.

1. speed-up, warm store: the same 2 trials (1 point x 2 seeds on the smoke grid's 3x3
   settings, configs/train/tiny.yaml with `team_sizes: lattice` and --steps TD3 steps,
   evaluated on 3 episodes) run 2 at once (workers=2: 0.5 CPU each, trial_cpus) and one
   after another (workers=1: 1 CPU), each into its own folder; target: 2 at once in
   <= 0.6 x the wall time of one after another. The store is warmed over the lattice
   first, so neither timed run computes a game (checked: the service's computations do
   not change). The default 6000 steps train about 80 s per trial on an idle core (about
   14 ms of CPU a step), so a run's fixed costs (Tune's start, a trial actor's imports,
   the tables: about 8 s a run) are a small part of it, as they are of a real trial of
   20,000 steps; measured on 2 idle cores: 178.6 s one after another, 91.2 s 2 at once,
   ratio 0.51 (at 3000 steps the fixed costs weigh more: 84.2 s against 51.6 s, 0.61).
2. single flight, cold store: 2 trials at once (tiny's 300 steps) on a new store without
   the lattice warm-up (run_experiment(warm=False)), so both trials ask the service for
   the same keys as they meet them; target: every distinct key asked (the service's
   `asked`) computed exactly once (its `computations`).
Conditions: one local 2-CPU Ray, started here (farm.runtime.ray_cluster) and joined by
every run_experiment, and one store and service actor for all: part 2 first, then the
warm-up, then part 1's runs, 2 at once first (whatever a run leaves warm, such as the OS
file cache, helps the run after it: the one the ratio divides by). A named actor lives
as long as a handle to it, so this script holds the service's handle: the actor and its
counts outlive each run_experiment, and neither timed run pays Ray's start nor the
actor's. A timed run is a whole Tune experiment: its trials' actors start, train,
evaluate, and the tables are written.
Usage: python benchmarks/experiments.py [--steps 6000] [--quick]   (about 5 min on 2 idle cores)
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

# benchmarks/farm.py would shadow the farm package: drop this folder from the path.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

ROOT = Path(__file__).resolve().parents[1]
TARGET_RATIO = 0.6
COLD_STEPS = 300  # configs/train/tiny.yaml's


def experiment(name: str, store: Path, steps: int):
    """1 point (C_capture 1.5) x 2 seeds of `steps` TD3 steps on tiny's 3x3 settings, team sizes
    on the lattice, a periodic evaluation and a checkpoint halfway, 3 evaluation episodes."""
    from farm.studies.experiments import ExperimentConfig

    every = max(1, steps // 2)
    return ExperimentConfig(name=name, base=str(ROOT / "configs" / "train" / "tiny.yaml"),
                            overrides={"env.team_sizes": "lattice", "td3.n_timesteps": steps, "eval.freq": every,
                                       "checkpoint_freq": every},
                            grid={"env.c_capture": [1.5]}, seeds=[0, 1], episodes=3, store=str(store))


def computed(stats: dict) -> int:
    """Computations the service has made (a key computed twice counts twice)."""
    return sum(stats["computations"].values())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=6000,
                    help="TD3 steps per trial of the timed runs (6000: about 80 s of training on an idle core)")
    ap.add_argument("--quick", action="store_true", help="1000 steps per trial: checks the script, not the target")
    a = ap.parse_args()
    steps = 1000 if a.quick else a.steps
    if steps < 1:
        ap.error(f"--steps: must be >= 1, got {steps}")
    from farm.alloc.game.config import AllocConfig
    from farm.alloc.game.lattice import lattice_pairs
    from farm.runtime import ray_cluster
    from farm.studies.experiments import plan, run_experiment

    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="farm-bench-experiments-") as tmp, \
            ray_cluster(num_cpus=2, dashboard=False):
        from farm.service import CaptureTimeClient, get_service  # imports Ray: after ray_cluster set its binding

        tmp = Path(tmp)
        store = tmp / "store.sqlite"
        env = AllocConfig(**plan(experiment("timed", store, steps)).trials[0].config["env"])
        # The actor every run_experiment finds, held here: it and its counts outlive each run.
        client = CaptureTimeClient(env.game_settings(), service=get_service(store))

        t0 = time.perf_counter()
        run_experiment(experiment("cold", store, COLD_STEPS), tmp / "cold", workers=2, show_progress=False, warm=False)
        t_cold = time.perf_counter() - t0
        cold = client.stats()

        t0 = time.perf_counter()
        client.warm(lattice_pairs(env))
        t_warm = time.perf_counter() - t0
        runs = {}
        for workers in (2, 1):
            before = computed(client.stats())
            t0 = time.perf_counter()
            trials, _, info = run_experiment(experiment("timed", store, steps), tmp / f"workers-{workers}",
                                             workers=workers, show_progress=False)
            runs[workers] = (time.perf_counter() - t0, trials, info, computed(client.stats()) - before)

    load = os.getloadavg()[0]
    print(f"2 trials of {steps} TD3 steps (1 point x 2 seeds, 3x3, team sizes on the lattice, 3 evaluation episodes); "
          f"one local Ray of 2 CPUs for every run (load average {load:.1f} over {os.cpu_count()} cores)")
    print(f"store warmed over {len(lattice_pairs(env))} lattice pairs in {t_warm:.1f} s; "
          f"keys computed during the timed runs: {runs[2][3] + runs[1][3]}")
    print(f"\n{'run':<40}{'wall s':>8}{'CPU/trial':>11}{'train s per trial':>20}{'ratio':>8}{'target':>9}")
    serial = runs[1][0]
    for workers, label in ((1, "one after another (workers=1)"), (2, "2 at once (workers=2)")):
        wall, trials, info, _ = runs[workers]
        train = ", ".join(f"{s:.1f}" for s in trials["train_seconds"])
        ratio, target = (f"{wall / serial:.2f}", f"<= {TARGET_RATIO:g}") if workers == 2 else ("", "")
        print(f"{label:<40}{wall:>8.1f}{info['trial_cpus']:>11g}{train:>20}{ratio:>8}{target:>9}")

    asked, keys = cold["asked"], cold["computations"]
    once = len(keys) == asked and all(n == 1 for n in keys.values())
    print(f"\ncold store, 2 trials of {COLD_STEPS} steps at once without warm-up ({t_cold:.1f} s):")
    print(f"{'  distinct keys the trials asked (asked)':<48}{asked:>8}")
    print(f"{'  keys computed (computations)':<48}{len(keys):>8}   times computed: {computed(cold)}")
    print(f"{'  asks that found their key in flight':<48}{cold['misses'] - computed(cold):>8}")
    print(f"{'  asks of a key computed before (hits)':<48}{cold['hits']:>8}")
    print(f"{'  every key computed exactly once':<48}{'yes' if once else 'NO':>8}   target: yes")
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
