"""The learned allocator's cost per step against receding_horizon's, side by side, on the 8x8 suite scenarios.

For each of larger_8x8 and wide_front_8x8 (farm.alloc.game.scenarios; gymnasium ids farm/<name>-v0):
the states of --episodes seeded episodes (seeds 1000..) played by receding_horizon (the expert
the learners' DAgger pretraining imitates, so the states a learner meets), then every policy's
predict(obs, deterministic=True) on those same observations, timed one by one:
  receding_horizon  the planner (farm.alloc.allocators, default options);
  ppo               the learned allocator: a stable-baselines3 PPO model built exactly as
                    configs/train/best_<scenario>.yaml builds it (farm.alloc.training.train.
                    make_model on its TrainConfig and the training env of its n_envs, as
                    farm train builds it: MlpPolicy, 400-300 pi and vf networks), its
                    policy wrapped by the registry's learned entry (make_allocator("ppo", ...,
                    policy=model.policy)), which is what `farm eval` and `farm suite` predict
                    through, with the config's `repair` (levels: farm.alloc.allocators.repair).
                    Its weights are untrained: the time of a step depends on the
                    architecture, not the weights, so no trained model.zip is needed;
  ppo network       the same network alone, without the repair;
  intercept         the cheap planner, for context.
ms/step is the mean CPU ms per predict() over the states (the suite's seconds_per_step is the
same mean: predict seconds over steps), the best of --repeats passes, the policies taken in
turn in each pass, after one untimed call each (imports, the planner's table of statistics).
One process pinned to one core, torch and the numerical libraries at one thread; CPU time
(time.process_time) because other work on a shared machine lengthens wall time (the wall ms
is printed beside it). Every lattice pair is in the client's memo before timing (a warm store,
as benchmarks/planners.py: its default store is the one that benchmark warms), so
receding_horizon's service queries are memo hits, never games.
                          target: ppo's ms/step <= 0.1 x receding_horizon's (printed, not asserted)
Usage: python benchmarks/learners.py [--store /tmp/swarm-farm-planners.sqlite] [--mode local|ray]
                                     [--episodes 10] [--repeats 3]   (about 20 s on a warm store;
                                     a cold one first computes the 256 lattice pairs, minutes)
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

SCENARIO_NAMES = ("larger_8x8", "wide_front_8x8")
CONFIGS = Path(__file__).resolve().parent.parent / "configs" / "train"
TARGET = 0.1  # the learned allocator's ms/step over receding_horizon's, at most


def states(config, client, episodes: int) -> list[np.ndarray]:
    """The observations of episodes seeded 1000.. of config, receding_horizon acting."""
    from farm.alloc import SwarmAllocationEnv
    from farm.alloc.allocators import make_allocator

    expert = make_allocator("receding_horizon", config, client)
    env = SwarmAllocationEnv(config, client=client)
    out = []
    for seed in range(1000, 1000 + episodes):
        obs, _ = env.reset(seed=seed)
        while True:
            out.append(np.array(obs, copy=True))
            action, _ = expert.predict(obs, deterministic=True)
            obs, _, term, trunc, _ = env.step(action)
            if term or trunc:
                break
    env.close()
    return out


def learned_policy(name: str, client, tmp: Path):
    """The registry's learned allocator over an untrained model built as configs/train/best_<name>.yaml builds it."""
    from farm.alloc.allocators import make_allocator
    from farm.alloc.training.config import load_train_config
    from farm.alloc.training.train import make_model, training_envs

    tc = load_train_config(CONFIGS / f"best_{name}.yaml")
    vec_env, _, _ = training_envs(tc, client)  # the env training builds the model on (n_envs batched episodes)
    model = make_model(tc, vec_env, tmp / name)
    return tc, make_allocator(tc.algo, tc.env, client, policy=model.policy, repair=tc.repair), model.policy


def timed(policies: dict, observations: list, repeats: int) -> dict:
    """{policy: (CPU ms, wall ms) per predict(), means over observations, the pass of least CPU
    time of `repeats`}, the policies in turn in each pass, after one untimed call each."""
    for policy in policies.values():
        policy.predict(observations[0], deterministic=True)
    best: dict = {}
    for _ in range(repeats):
        for name, policy in policies.items():
            cpu = wall = 0.0
            for obs in observations:
                c0, t0 = time.process_time(), time.perf_counter()
                policy.predict(obs, deterministic=True)
                cpu += time.process_time() - c0
                wall += time.perf_counter() - t0
            got = (1e3 * cpu / len(observations), 1e3 * wall / len(observations))
            if name not in best or got[0] < best[name][0]:
                best[name] = got
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--store", default="/tmp/swarm-farm-planners.sqlite", help="the capture-time store (warmed)")
    ap.add_argument("--mode", choices=["local", "ray"], default="local", help="warm in process or on a local Ray")
    ap.add_argument("--episodes", type=int, default=10, help="episodes (seeds 1000..) whose states are timed")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    import torch

    from farm.alloc.allocators import make_allocator
    from farm.alloc.game.lattice import memo_client
    from farm.alloc.game.scenarios import SCENARIOS

    torch.set_num_threads(1)
    configs = {name: SCENARIOS[name].config() for name in SCENARIO_NAMES}
    client, pairs, t_warm = memo_client(configs.values(), a.mode, a.store)  # every lattice pair in its memo
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core from here on
    print(f"store {a.store}: {len(pairs)} lattice pairs warm ({a.mode}) in {t_warm:.1f} s; timing on one core, "
          f"torch threads {torch.get_num_threads()} (load average {os.getloadavg()[0]:.1f} over "
          f"{os.cpu_count()} cores)")

    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in SCENARIO_NAMES:
            config = configs[name]
            tc, learned, network = learned_policy(name, client, Path(tmp))
            assert tc.env == config, f"best_{name}.yaml's env is not the scenario's"
            observations = states(config, client, a.episodes)
            policies = {"receding_horizon": make_allocator("receding_horizon", config, client), tc.algo: learned,
                        f"{tc.algo} network": network, "intercept": make_allocator("intercept", config, client)}
            misses = client.stats()["misses"]
            costs = timed(policies, observations, a.repeats)
            assert client.stats()["misses"] == misses, "a service query missed the memo while timing"
            arch = tc.learner.policy_kwargs.get("net_arch")
            rows += [(name, policy, len(observations), cpu, wall, tc.algo == policy, arch)
                     for policy, (cpu, wall) in costs.items()]
    client.close()

    print(f"\nCPU ms per predict(obs, deterministic=True), mean over the states of {a.episodes} receding_horizon "
          f"episodes (seeds 1000..), best of {a.repeats}; target: learned <= {TARGET:g} x receding_horizon")
    print(f"{'scenario':<16}{'policy':<18}{'states':>7}{'ms/step':>10}{'wall ms':>10}{'/rh':>9}{'target':>8}")
    for name, policy, n, cpu, wall, is_learned, _ in rows:
        rh = next(r[3] for r in rows if r[0] == name and r[1] == "receding_horizon")
        ratio = cpu / rh
        met = ("yes" if ratio <= TARGET else "no") if is_learned else ""
        print(f"{name:<16}{policy:<18}{n:>7}{cpu:>10.3f}{wall:>10.3f}{ratio:>9.4f}{met:>8}")
    arch = next(r[6] for r in rows if r[5])
    print(f"learned: untrained PPO built by make_model from configs/train/best_<scenario>.yaml (net_arch {arch}), "
          f"through the registry's ppo entry; ({time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    main()
