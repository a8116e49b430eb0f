"""Allocation env and TD3 trainer costs, one process, one core for torch.

1. env step time with a warm capture-time cache (memo hits only)   target <= 0.2 ms
2. share of TD3 training wall time spent outside the networks' updates (env steps,
   action selection, replay buffer, callbacks), measured, no longer a target: stock
   stable-baselines3 TD3 on DummyVecEnv timed two ways side by side (an override of the
   public train(), and farm's UpdateTimer callback), and the whole `farm train` loop
   (paper 3x3 hyperparameters with its evaluation, checkpoint-with-replay-buffer and
   progress callbacks).
Usage: python benchmarks/alloc.py [--steps 3000] [--train-steps 20000]   (about 8 min)
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
    ap.add_argument("--steps", type=int, default=3000, help="TD3.learn steps per bare row")
    ap.add_argument("--train-steps", type=int, default=20000, help="steps of the farm train row (the paper run: 20000)")
    a = ap.parse_args()
    import torch
    from stable_baselines3 import TD3
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from farm.alloc import AllocConfig, SwarmAllocationEnv
    from farm.alloc.game.lattice import lattice_pairs
    from farm.alloc.training import ServiceParams, TrainConfig, UpdateTimer, load_train_config, train
    from farm.service import CaptureTimeClient

    torch.set_num_threads(1)
    config = AllocConfig(grid_size=3, n_defenders=100, n_intruders=50, c_capture=1.5, team_sizes="lattice",
                         games=4)
    paper = load_train_config(Path(__file__).resolve().parents[1] / "configs/train/paper_3x3_c1_1.5.yaml")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "s.sqlite"
        client = CaptureTimeClient(config.game_settings(), local_store=store)
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

        class TimedTD3(TD3):
            train_seconds = 0.0

            def train(self, gradient_steps, batch_size=100):
                t = time.perf_counter()
                super().train(gradient_steps, batch_size)
                self.train_seconds += time.perf_counter() - t

        model = TimedTD3("MlpPolicy", DummyVecEnv([lambda: Monitor(env)]), learning_starts=100, batch_size=256,
                         seed=0, device="cpu", verbose=0, policy_kwargs={"net_arch": [400, 300]})
        timer = UpdateTimer()
        t0 = time.perf_counter()
        model.learn(total_timesteps=a.steps, callback=timer)
        total = time.perf_counter() - t0
        rows.append((f"TD3 learn {a.steps} steps, train() timed", total, a.steps, 1 - model.train_seconds / total))
        rows.append(("the same, UpdateTimer callback", total, a.steps, 1 - timer.update_seconds / total))

        run = TrainConfig(name="bench", seed=0, env=config,
                          td3=paper.td3.model_copy(update={"n_timesteps": a.train_steps}),
                          eval=paper.eval, checkpoint_freq=paper.checkpoint_freq,
                          service=ServiceParams(mode="local", store=str(store)))
        m = train(run, Path(tmp) / "run", show_progress=False)
        rows.append((f"farm train, {a.train_steps} steps, callbacks", m["wall_seconds"], a.train_steps,
                     m["outside_update_share"]))
    print(f"lattice warm-up (in-process, {len(lattice_pairs(config))} cases, 4 games each): {t_warm:.1f} s")
    print(f"env step, warm cache: {step_ms:.3f} ms   (target <= 0.2 ms)")
    print(f"{'TD3 400-300, batch 256, train_freq 1':<44}{'wall':>8}{'steps/s':>9}{'outside updates':>17}")
    for label, wall, steps, outside in rows:
        print(f"{label:<44}{wall:>7.1f}s{steps / wall:>9.0f}{100 * outside:>16.1f}%")


if __name__ == "__main__":
    main()
