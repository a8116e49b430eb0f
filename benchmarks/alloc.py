"""Allocation env and TD3 trainer costs, one process.

1. env step time with a warm capture-time cache (memo hits only)   target <= 0.2 ms
2. share of TD3 training wall time spent outside the networks' updates
   (env steps, action selection, replay buffer, callbacks)        target <= 5 %
Usage: python benchmarks/alloc.py [--steps 3000]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=3000)
    a = ap.parse_args()
    import torch
    from stable_baselines3 import TD3

    from farm.alloc import AllocConfig, SwarmAllocationEnv
    from farm.service import CaptureTimeClient

    torch.set_num_threads(1)
    config = AllocConfig(grid_size=3, n_defenders=100, n_intruders=50, c_capture=1.5, team_sizes="lattice",
                         games=4, t_max=6.0)
    with tempfile.TemporaryDirectory() as tmp:
        probe = SwarmAllocationEnv(config, client=object())
        client = CaptureTimeClient(probe.service_settings(), local_store=Path(tmp) / "s.sqlite")
        from farm.alloc.train import TrainConfig, lattice_pairs

        t0 = time.perf_counter()
        client.get_many(lattice_pairs(config))
        t_warm = time.perf_counter() - t0
        env = SwarmAllocationEnv(config, client=client)
        rng = np.random.default_rng(0)
        actions = rng.uniform(-1, 1, (4096,) + env.action_space.shape).astype(np.float32)
        env.reset(seed=0)
        for i in range(500):  # warm every reachable key
            if any(env.step(actions[i % 4096])[2:4]):
                env.reset(seed=i)
        n, t0 = 0, time.perf_counter()
        env.reset(seed=1)
        while n < 20_000:
            _, _, term, trunc, _ = env.step(actions[n % 4096])
            n += 1
            if term or trunc:
                env.reset(seed=n)
        step_ms = (time.perf_counter() - t0) / n * 1e3

        model = TD3("MlpPolicy", env, learning_starts=100, batch_size=256, policy_kwargs={"net_arch": [400, 300]},
                    seed=0, device="cpu", verbose=0)
        spent = {"train": 0.0}
        original = model.train

        def timed_train(*args, **kwargs):
            t = time.perf_counter()
            original(*args, **kwargs)
            spent["train"] += time.perf_counter() - t

        model.train = timed_train
        t0 = time.perf_counter()
        model.learn(total_timesteps=a.steps)
        total = time.perf_counter() - t0
    outside = 1 - spent["train"] / total
    print(f"lattice warm-up (in-process, {len(lattice_pairs(config))} cases, 4 games each): {t_warm:.1f} s")
    print(f"{'measure':<52}{'value':>10}{'target':>10}")
    print(f"{'env step, warm cache':<52}{step_ms:>8.3f}ms{'<= 0.2ms':>10}")
    print(f"{f'TD3 400-300, {a.steps} steps: wall':<52}{total:>9.1f}s{'':>10}  ({a.steps / total:.0f} steps/s)")
    print(f"{'  share outside the networks updates':<52}{100 * outside:>9.1f}%{'<= 5%':>10}")


if __name__ == "__main__":
    main()
