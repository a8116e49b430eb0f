"""Batched allocation env against one env per episode, side by side, one process, one core.

1. env steps/s, random actions, B = 16 episodes: farm.alloc.envs.vector.SwarmAllocationVectorEnv
   against gymnasium's SyncVectorEnv of 16 SwarmAllocationEnv (both SAME_STEP autoreset), the
   same config and in-process client over a warmed store (every lookup a memo hit); a 3x3 and a
   5x5 config.                                                          target >= 5x at 16 envs
2. PPO training steps/s (stable-baselines3 PPO, MlpPolicy, n_steps 64 per env, 16 envs, the
   3x3 config): farm.alloc.envs.sb3_vec.make_vec_env (the batched env adapted, in a VecMonitor)
   against SB3's DummyVecEnv of 16 Monitor-wrapped single envs; learn()'s steps/s, and its time
   split into rollouts (the env's part) and updates, with SB3's (and the project's) default
   updates, batch_size 64 and n_epochs 10, with lighter ones, n_epochs 1, and with the
   learners' recipe (configs/train/best_<scenario>.yaml: 400-300 tanh networks, n_steps 256,
   batch_size 512, n_epochs 10; 4 rollouts of 4,096 steps).                       target >= 2x
3. two-sided env steps, B = 16 episodes, random actions, the configs of 1: a batched step whose
   intruders' routing comes from an intruder action inside the step, against today's batched
   step (SwarmAllocationVectorEnv, the drift law): the defenders' batched env with a heuristic
   intruder policy (fewest_ahead, follower: routed from the defenders after their move), and the
   intruders' batched env (farm.alloc.envs.intruders.SwarmIntruderVectorEnv, follower) against a
   cheap frozen allocator (stay_at_base) and against intercept. Cost ratio = CPU time of the
   two-sided step / the drift step's.                               target <= 1.5x
Rates are of this process's CPU time (time.process_time: other load on the machine does not
count), the best of --repeats runs, the two sides of a row run in turn.
Usage: python benchmarks/vector_env.py [--steps 1500] [--ppo-steps 8192] [--repeats 3] [--skip-ppo]
(about 4 min; --skip-ppo: sections 1 and 3 alone, about 1 min)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

ENVS = 16
# configs/train/best_<scenario>.yaml's PPO (its 400-300 tanh networks, log_std_init -1)
RECIPE = dict(n_steps=256, batch_size=512, n_epochs=10, learning_rate=1e-4, gamma=0.99,
              policy_kwargs=dict(net_arch=dict(pi=[400, 300], vf=[400, 300]), log_std_init=-1.0))


def env_seconds(env, actions: np.ndarray, steps: int) -> float:
    """CPU seconds of `steps` vector steps of a vector env (ENVS env steps each), after a warm-up."""
    env.reset(seed=0)
    for t in range(200):
        env.step(actions[t % len(actions)])
    t0 = time.process_time()
    for t in range(steps):
        env.step(actions[t % len(actions)])
    return time.process_time() - t0


def ppo_seconds(make_env, steps: int, **ppo) -> tuple[float, float]:
    """(CPU seconds of PPO.learn(steps) on a fresh SB3 VecEnv from make_env(), of which in its
    updates, PPO.train), after a warm-up rollout and update; ppo: PPO's keyword arguments."""
    from stable_baselines3 import PPO

    class TimedPPO(PPO):
        train_seconds = 0.0

        def train(self):
            t = time.process_time()
            super().train()
            self.train_seconds += time.process_time() - t

    model = TimedPPO("MlpPolicy", make_env(), seed=0, device="cpu", verbose=0, **ppo)
    model.learn(total_timesteps=model.n_steps * ENVS)
    model.train_seconds = 0.0
    t0 = time.process_time()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return time.process_time() - t0, model.train_seconds


def best_of(repeats: int, runs: dict) -> dict:
    """Each run's least result over `repeats` turns, the runs taken in turn each time (runs:
    name -> a function returning seconds, or a tuple whose first entry is compared)."""
    best: dict = {}
    for _ in range(repeats):
        for name, run in runs.items():
            got = run()
            key = got[0] if isinstance(got, tuple) else got
            if name not in best or key < best[name][0]:
                best[name] = (key, got)
    return {name: got for name, (_, got) in best.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1500, help="vector steps per env run (x16 env steps)")
    ap.add_argument("--ppo-steps", type=int, default=8192, help="PPO.learn steps per PPO run")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each side, the best counted")
    ap.add_argument("--skip-ppo", action="store_true", help="skip the PPO section (2)")
    a = ap.parse_args()
    import gymnasium
    import torch
    from gymnasium.vector import AutoresetMode
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from farm.alloc import AllocConfig, SwarmAllocationEnv
    from farm.alloc.envs.intruders import SwarmIntruderVectorEnv
    from farm.alloc.envs.sb3_vec import make_vec_env
    from farm.alloc.envs.vector import SwarmAllocationVectorEnv
    from farm.alloc.game.lattice import lattice_groups, warm_lattices
    from farm.service import CaptureTimeClient

    torch.set_num_threads(1)
    configs = {
        "3x3, 100 v 50": AllocConfig(grid_size=3, n_defenders=100, n_intruders=50, c_capture=1.5,
                                     team_sizes="lattice", games=4),
        "5x5, 100 v 50": AllocConfig(grid_size=5, n_defenders=100, n_intruders=50, c_capture=1.5, max_steps=16,
                                     team_sizes="lattice", games=4),
    }
    env_rows, ppo_rows, two_sided_rows = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        first = next(iter(configs.values()))
        client = CaptureTimeClient(first.game_settings(), local_store=Path(tmp) / "s.sqlite")
        t0 = time.perf_counter()
        cases = warm_lattices(client, lattice_groups(configs.values()), show_progress=False)
        t_warm = time.perf_counter() - t0
        for label, config in configs.items():
            single = SwarmAllocationEnv(config, client=client)
            actions = np.random.default_rng(0).uniform(-1, 1, (512, ENVS) + single.action_space.shape)
            actions = actions.astype(np.float32)
            batched = SwarmAllocationVectorEnv(config, num_envs=ENVS, client=client)
            sync = gymnasium.vector.SyncVectorEnv([lambda config=config: SwarmAllocationEnv(config, client=client)]
                                                  * ENVS, autoreset_mode=AutoresetMode.SAME_STEP)
            best = best_of(a.repeats, {"batched": lambda env=batched, x=actions: env_seconds(env, x, a.steps),
                                       "sync": lambda env=sync, x=actions: env_seconds(env, x, a.steps)})
            env_rows.append((label, a.steps * ENVS / best["batched"], a.steps * ENVS / best["sync"]))
            rng = np.random.default_rng(1)
            intruder_actions = rng.uniform(-1, 1, (512, ENVS, config.grid_size * (3 * config.grid_size - 2)))
            intruder_actions = intruder_actions.astype(np.float32)
            two_sided = {
                "drift": (batched, actions),
                "defenders' env, fewest_ahead": (SwarmAllocationVectorEnv(
                    config.model_copy(update={"intruders": "fewest_ahead"}), num_envs=ENVS, client=client), actions),
                "intruders' env v stay_at_base": (SwarmIntruderVectorEnv(
                    config, num_envs=ENVS, opponent="stay_at_base", client=client), intruder_actions),
                "intruders' env v intercept": (SwarmIntruderVectorEnv(
                    config, num_envs=ENVS, opponent="intercept", client=client), intruder_actions),
            }
            best = best_of(a.repeats, {name: (lambda env=env, acts=acts: env_seconds(env, acts, a.steps))
                                       for name, (env, acts) in two_sided.items()})
            two_sided_rows += [(f"{label}, {name}", a.steps * ENVS / best[name], best[name] / best["drift"])
                               for name in two_sided]
        label, config = next(iter(configs.items()))

        def dummy():
            return DummyVecEnv([lambda: Monitor(SwarmAllocationEnv(config, client=client))] * ENVS)

        settings = {"n_epochs 10": dict(n_steps=64, batch_size=64, n_epochs=10),
                    "n_epochs 1": dict(n_steps=64, batch_size=64, n_epochs=1),
                    "learners' recipe": RECIPE}
        for name, ppo in ({} if a.skip_ppo else settings).items():
            steps = a.ppo_steps if ppo["n_steps"] * ENVS <= a.ppo_steps else 4 * ppo["n_steps"] * ENVS
            best = best_of(a.repeats, {
                "batched": lambda n=steps, kw=ppo: ppo_seconds(lambda: make_vec_env(config, ENVS, client, seed=0),
                                                               n, **kw),
                "dummy": lambda n=steps, kw=ppo: ppo_seconds(dummy, n, **kw)})
            ppo_rows.append((f"{label}, {name}", steps, best["batched"], best["dummy"]))
        client.close()
    print(f"lattice warm-up (in-process, {cases} cases, 4 games each): {t_warm:.1f} s; torch threads 1; "
          f"CPU time, best of {a.repeats}")
    print(f"{'env steps/s, 16 envs, random actions':<40}{'batched':>9}{'SyncVectorEnv':>15}{'ratio':>8}"
          f"   (target >= 5x)")
    for label, ours, sync in env_rows:
        print(f"{label:<40}{ours:>9.0f}{sync:>15.0f}{ours / sync:>7.1f}x")
    print(f"{'PPO, 16 envs':<40}{'batched':>9}{'DummyVecEnv':>15}{'ratio':>8}"
          f"   (target >= 2x)")
    for label, steps, (ours, ours_train), (other, other_train) in ppo_rows:
        print(f"{label + ': learn steps/s':<40}{steps / ours:>9.0f}{steps / other:>15.0f}{other / ours:>7.1f}x")
        print(f"{'  rollouts alone, steps/s':<40}{steps / (ours - ours_train):>9.0f}"
              f"{steps / (other - other_train):>15.0f}{(other - other_train) / (ours - ours_train):>7.1f}x")
        print(f"{'  updates, s of learn s':<40}{f'{ours_train:.1f}/{ours:.1f}':>9}"
              f"{f'{other_train:.1f}/{other:.1f}':>15}")
    print(f"{'two-sided env steps/s, 16 envs (drift: today)':<48}{'steps/s':>9}{'cost v drift':>14}"
          f"   (target <= 1.5x)")
    for label, rate, ratio in two_sided_rows:
        print(f"{label:<48}{rate:>9.0f}{ratio:>13.2f}x")


if __name__ == "__main__":
    main()
