"""Allocators at scale: each allocator's time per step on 3x3, 8x8, 16x16 and 32x32 maps, side by
side, and the live engagements' games/s at 32x32 on 1 and 2 workers.

Part 1, time per step. For each of outnumbered_3x3, theatre_8x8, theatre_16x16 and theatre_32x32
(farm.alloc.game.scenarios), the states of --episodes seeded episodes (seeds 1000..) played by the
intercept planner, --states of them evenly spaced, then every allocator's
predict(obs, deterministic=True) on those same observations, timed one by one, in turn:
  stay_at_base, greedy_nearest, spread_evenly, intercept, transport, mmr, receding_horizon: the registry's
      baselines and planners (default options);
  ppo (CellPolicy): the size-free learner, a PPO model built exactly as
      configs/train/size_free_transport.yaml builds it (on theatre_8x8), its weights moved to each map by
      the registry's learned entry (make_allocator("ppo", config, policy=...): cell_policy.resized),
      as `farm eval RUN --scenario NAME` does; --run RUN times a trained run's instead. A step's
      time depends on the architecture and the map, not on the weights. Its actions go through
      the level repair when size_free_transport.yaml (or the run) says `repair: levels`, as they do in
      `farm eval`;
  ppo network: the same network alone, without the repair.
ms/step is CPU ms per predict(), mean over the states, best of --repeats passes, after one
untimed call each; one process pinned to one core, torch and the numerical libraries at one
thread; every lattice pair is in the client's memo before timing (farm.alloc.game.lattice.memo_client),
so no planner's query is a game or a store read.
    target (issue 26): ppo's ms/step <= 1/20 of receding_horizon's on the theatres (printed)

Part 2, live engagements (`farm eval --fidelity games`, farm.alloc.evaluation.fidelity): --live-episodes
episodes of theatre_32x32 (its own 16 v 5,000 by default; --live-defenders changes the
defenders) under the intercept planner, stepped together, every engaged cell's game played
live (each engagement its own game: about 230 a step with 32 episodes, some 1.7 s of work) as
coarse Ray tasks (about fidelity.TASK_SECONDS of work each by the engine's cost model plus
fidelity.CALL_SECONDS a game, a small step cut in fidelity.TASKS_PER_CPU tasks a CPU, at
most twice the CPUs pending), on a local Ray of 1 and then of 2 CPUs (one worker each);
games/s is games over the wall seconds spent playing them. A step's tasks wait for the
step's policy and the next step for its last task, so fewer episodes (less work a step)
share less well: 16 episodes give about 1.7x. --address ADDR also runs it on a running
cluster (e.g. two nodes of `ray start`).
    target: games/s on 2 workers >= 1.8 x on 1 (printed)

Part 3 (--subregions), sub-region planning against the whole map: on theatre_16x16 and
theatre_32x32, --sub-episodes episodes (seeds 1000..) of receding_horizon on the whole map and
of subregions (farm.alloc.allocators.planners.subregions) with 2 and 4 bands planned by
receding_horizon, in this process and on 2 Ray actors; eliminated mass, return and wall ms a
step.

Usage: python benchmarks/theatre.py [--store /tmp/swarm-farm-planners.sqlite] [--episodes 1]
         [--states 8] [--repeats 2] [--live-episodes 32] [--live-defenders N] [--run RUN]
         [--address ADDR] [--skip-steps] [--skip-live] [--subregions] [--sub-episodes 2]
         (about 10 minutes on a warm store: receding_horizon takes seconds a step at 32x32)
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")
# benchmarks/farm.py would shadow the farm package: drop this folder from the path.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

MAPS = ("outnumbered_3x3", "theatre_8x8", "theatre_16x16", "theatre_32x32")
REFERENCES = ("stay_at_base", "greedy_nearest", "spread_evenly", "intercept", "transport", "mmr", "receding_horizon")
CONFIG = Path(__file__).resolve().parent.parent / "configs" / "train" / "size_free_transport.yaml"
STEP_TARGET = 1 / 20  # the size-free learner's ms/step over receding_horizon's, at most
LIVE_TARGET = 1.8  # games/s on 2 workers over 1, at least


def states(config, client, episodes: int, keep: int) -> list[np.ndarray]:
    """keep observations, evenly spaced, of episodes seeded 1000.. of config, intercept acting."""
    from farm.alloc import SwarmAllocationEnv
    from farm.alloc.allocators import make_allocator

    planner = make_allocator("intercept", config, client)
    env = SwarmAllocationEnv(config, client=client)
    out = []
    for seed in range(1000, 1000 + episodes):
        obs, _ = env.reset(seed=seed)
        while True:
            out.append(np.array(obs, copy=True))
            obs, _, term, trunc, _ = env.step(planner.predict(obs)[0])
            if term or trunc:
                break
    env.close()
    return [out[int(k)] for k in np.linspace(0, len(out) - 1, min(keep, len(out)))]


def size_free_policy(client, run: str | None):
    """The size-free learner's policy: a trained run's, or an untrained one built as
    size_free_transport.yaml builds it."""
    if run is not None:
        from farm.alloc.allocators.learned import load_model

        return load_model(run, "ppo").policy
    from farm.alloc.training.config import load_train_config
    from farm.alloc.training.train import make_model, training_envs

    tc = load_train_config(CONFIG)
    with tempfile.TemporaryDirectory() as tmp:
        vec_env, _, _ = training_envs(tc, client)
        return make_model(tc, vec_env, Path(tmp)).policy


def timed(policies: dict, observations: list, repeats: int) -> dict:
    """{policy: CPU ms per predict(), mean over observations, the best of `repeats` passes}."""
    for policy in policies.values():
        policy.predict(observations[0], deterministic=True)
    best: dict = {}
    for _ in range(repeats):
        for name, policy in policies.items():
            c0 = time.process_time()
            for obs in observations:
                policy.predict(obs, deterministic=True)
            ms = 1e3 * (time.process_time() - c0) / len(observations)
            best[name] = min(ms, best.get(name, np.inf))
    return best


def step_times(a) -> None:
    import torch

    from farm.alloc.allocators import make_allocator
    from farm.alloc.game.lattice import memo_client
    from farm.alloc.game.scenarios import SCENARIOS
    from farm.alloc.training.config import load_train_config

    torch.set_num_threads(1)
    configs = {name: SCENARIOS[name].config() for name in MAPS}
    client, pairs, t_warm = memo_client(configs.values(), "local", a.store)
    trained = size_free_policy(client, a.run)
    repair = None if a.run else load_train_config(CONFIG).repair  # None: the run's own setting
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core from here on
    print(f"store {a.store}: {len(pairs)} lattice pairs warm in {t_warm:.1f} s; timing on one core (load average "
          f"{os.getloadavg()[0]:.1f} over {os.cpu_count()} cores)")
    table = {}
    for name, config in configs.items():
        observations = states(config, client, a.episodes, a.states)
        policies = {p: make_allocator(p, config, client) for p in REFERENCES}
        policies["ppo"] = make_allocator("ppo", config, client, policy=trained, run=a.run, repair=repair)
        policies["ppo network"] = make_allocator("ppo", config, client, policy=trained, repair="none")
        misses = client.stats()["misses"]
        table[name] = timed(policies, observations, a.repeats)
        assert client.stats()["misses"] == misses, "a service query missed the memo while timing"
        print(f"  {name}: {len(observations)} states timed", flush=True)
    client.close()
    names = [*REFERENCES, "ppo", "ppo network"]
    print(f"\nCPU ms per predict(obs), mean over {a.states} states of intercept's episodes, best of {a.repeats}; "
          f"ppo: CellPolicy ({'run ' + a.run if a.run else 'untrained, as size_free_transport.yaml builds it'})")
    print(f"{'allocator':<18}" + "".join(f"{m:>17}" for m in MAPS))
    for p in names:
        print(f"{p:<18}" + "".join(f"{table[m][p]:>17.3f}" for m in MAPS))
    ratios = {m: table[m]["ppo"] / table[m]["receding_horizon"] for m in MAPS}
    print(f"{'ppo / rh':<18}" + "".join(f"{ratios[m]:>17.4f}" for m in MAPS))
    met = all(ratios[m] <= STEP_TARGET for m in ("theatre_16x16", "theatre_32x32"))
    print(f"target ppo <= {STEP_TARGET:.3f} x receding_horizon on the theatres: {'met' if met else 'NOT met'}")


def live(a) -> None:
    from farm.alloc.allocators import make_allocator
    from farm.alloc.evaluation.fidelity import TASK_SECONDS, evaluate_fidelity
    from farm.alloc.game.lattice import memo_client
    from farm.alloc.game.scenarios import SCENARIOS
    from farm.runtime import ray_cluster

    defenders = {} if a.live_defenders is None else {"n_defenders": a.live_defenders}
    config = SCENARIOS["theatre_32x32"].config(**defenders)
    client, _, _ = memo_client([config], "local", a.store)
    policies = {"intercept": make_allocator("intercept", config, client)}
    runs = [(f"local Ray, {w} CPU(s)", dict(num_cpus=w)) for w in (1, 2)]
    if a.address:
        runs.append((f"cluster {a.address}", dict(address=a.address)))
    results = []
    for label, options in runs:
        with ray_cluster(**options):
            import ray

            cpus = int(ray.cluster_resources().get("CPU", 1))
            _, _, got = evaluate_fidelity(config, policies, client, a.live_episodes, 1000)
        results.append((label, cpus, got))
        print(f"  {label}: {got['games']} games in {got['tasks']} tasks, {got['games_per_second']:.0f} games/s",
              flush=True)
    client.close()
    base = results[0][2]["games_per_second"]
    print(f"\nlive engagements, theatre_32x32 with {config.n_defenders:,} defenders, intercept, "
          f"{a.live_episodes} episodes stepped together; tasks of at most {TASK_SECONDS} s by the cost model "
          "(fidelity.task_seconds)")
    print(f"{'where':<34}{'CPUs':>6}{'games':>8}{'tasks':>7}{'games/task':>12}{'games/s':>10}{'x 1 CPU':>9}")
    for label, cpus, got in results:
        print(f"{label:<34}{cpus:>6}{got['games']:>8}{got['tasks']:>7}{got['games'] / max(1, got['tasks']):>12.1f}"
              f"{got['games_per_second']:>10.0f}{got['games_per_second'] / base:>9.2f}")
    ratio = results[1][2]["games_per_second"] / base
    print(f"target 2 workers >= {LIVE_TARGET} x 1: {'met' if ratio >= LIVE_TARGET else 'NOT met'} ({ratio:.2f}x)")


class Timed:
    """An allocator whose predict() calls are counted and their wall seconds summed."""

    def __init__(self, policy):
        self.policy, self.calls, self.seconds = policy, 0, 0.0

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        t0 = time.perf_counter()
        out = self.policy.predict(obs, state, episode_start, deterministic)
        self.seconds += time.perf_counter() - t0
        self.calls += 1
        return out


def subregions(a) -> None:
    from farm.alloc.allocators import make_allocator
    from farm.alloc.evaluation.rollout import evaluate_policies
    from farm.alloc.game.lattice import memo_client
    from farm.alloc.game.scenarios import SCENARIOS
    from farm.runtime import ray_cluster
    from farm.service import CaptureTimeClient

    rows = []
    for name in ("theatre_16x16", "theatre_32x32"):
        config = SCENARIOS[name].config()
        client, _, _ = memo_client([config], "local", a.store)
        variants = {"receding_horizon": dict(name="receding_horizon")}
        for regions in (2, 4):
            variants[f"subregions {regions} bands"] = dict(name="subregions", regions=regions)
        variants["subregions 4 bands, 2 actors"] = dict(name="subregions", regions=4, workers=2)
        with ray_cluster(num_cpus=2):
            for label, options in variants.items():
                options = dict(options)
                policy_name = options.pop("name")
                # the actors open the store themselves: they get a client of the store, not the memo
                own = (CaptureTimeClient(config.game_settings(), local_store=a.store) if options.get("workers")
                       else client)
                policy = Timed(make_allocator(policy_name, config, own, **options))
                table = evaluate_policies(config, {label: policy}, client, a.sub_episodes, 1000)[0]
                if hasattr(policy.policy, "close"):  # subregions: its actors
                    policy.policy.close()
                if own is not client:
                    own.close()
                row = table.iloc[0]
                rows.append((name, label, row["eliminated_mean"], row["eliminated_ci95"], row["return_mean"],
                             1e3 * policy.seconds / max(1, policy.calls)))
                print(f"  {name} {label}: eliminated {row['eliminated_mean']:.3f}, "
                      f"{rows[-1][-1]:.0f} ms/step", flush=True)
        client.close()
    print(f"\nsub-regions against the whole map: {a.sub_episodes} episodes (seeds 1000..), wall ms per step "
          f"(predict), bands planned by receding_horizon; a local Ray of 2 CPUs for the actors")
    print(f"{'map':<15}{'planner':<32}{'eliminated':>17}{'return':>10}{'ms/step':>10}{'x whole':>9}")
    whole = {m: (e, ms) for m, label, e, _, _, ms in rows if label == "receding_horizon"}
    for m, label, e, ci, ret, ms in rows:
        print(f"{m:<15}{label:<32}{e:>10.3f} ± {ci:<5.3f}{ret:>10.3f}{ms:>10.0f}{ms / whole[m][1]:>9.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default="/tmp/swarm-farm-planners.sqlite", help="the capture-time store (warmed)")
    ap.add_argument("--episodes", type=int, default=1, help="intercept episodes (seeds 1000..) whose states are timed")
    ap.add_argument("--states", type=int, default=8, help="states timed per map, evenly spaced")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--live-episodes", type=int, default=32, help="theatre_32x32 episodes of the live part")
    ap.add_argument("--live-defenders", type=int, default=None,
                    help="theatre_32x32's defenders in the live part (default: its own 16)")
    ap.add_argument("--run", help="a trained size-free run folder to time instead of an untrained CellPolicy")
    ap.add_argument("--address", help="also run the live part on this running Ray cluster")
    ap.add_argument("--skip-steps", action="store_true", help="only the live part")
    ap.add_argument("--skip-live", action="store_true", help="no live part")
    ap.add_argument("--subregions", action="store_true", help="also part 3: sub-region planning against the whole map")
    ap.add_argument("--sub-episodes", type=int, default=2, help="part 3's episodes per map and planner")
    a = ap.parse_args()
    t0 = time.perf_counter()
    if a.subregions:
        subregions(a)
    if not a.skip_live:
        live(a)  # before part 1, which pins this process to one core
    if not a.skip_steps:
        step_times(a)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
