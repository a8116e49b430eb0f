"""The trainer uses stable-baselines3 as it ships: the update timer is a plain callback
that changes nothing in training, and measures what an override of train() measures;
the lattice snap of team sizes."""

import time

import numpy as np
import pytest
import torch
from stable_baselines3 import TD3
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.alloc.game.model import LATTICE, snap, snap_many
from farm.alloc.training import UpdateTimer

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3, c_capture=1.5)
NET = {"net_arch": [400, 300]}


def make(store):
    return DummyVecEnv([lambda: Monitor(SwarmAllocationEnv(AllocConfig(**SMALL), store=store))])


def test_snap_is_the_nearest_lattice_size_in_log_scale():
    import math

    x = np.arange(1, 5001)
    slow = [min(LATTICE, key=lambda v: (abs(math.log(v) - math.log(int(n))), v)) for n in x]
    assert snap_many(x).tolist() == slow
    assert [snap(int(n)) for n in x[:300]] == slow[:300]
    assert snap(100_000) == 256 and set(snap_many(x).tolist()) == set(LATTICE)


class TimedTD3(TD3):
    """An independent clock: SB3's public train() timed from inside."""

    train_seconds = 0.0

    def train(self, gradient_steps, batch_size=100):
        t0 = time.perf_counter()
        super().train(gradient_steps, batch_size)
        self.train_seconds += time.perf_counter() - t0


@pytest.mark.slow
def test_update_timer_measures_the_updates_and_changes_nothing(store):
    """Same seed with and without the timer: the same transitions and the same trained actor
    (the callback only reads the clock). The timer's update time covers every train() call
    (an override of train() measures it from inside) and little more."""
    models = []
    for timer in (None, UpdateTimer()):
        torch.manual_seed(0)
        model = TimedTD3("MlpPolicy", make(store), policy_kwargs=NET, learning_starts=60, batch_size=32, seed=3,
                         device="cpu")
        model.learn(200, callback=timer)
        models.append((model, timer))
    (plain, _), (timed, timer) = models
    np.testing.assert_array_equal(plain.replay_buffer.actions[:200], timed.replay_buffer.actions[:200])
    np.testing.assert_array_equal(plain.replay_buffer.rewards[:200], timed.replay_buffer.rewards[:200])
    for a, b in zip(plain.actor.parameters(), timed.actor.parameters()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert timed.train_seconds > 0
    assert timed.train_seconds <= timer.update_seconds <= timed.train_seconds + 0.5 * timed.train_seconds + 0.05


def test_training_leaves_the_thread_setting_as_it_was(tmp_path):
    """`threads` applies while a run trains; the caller's torch setting is back afterwards."""
    from farm.alloc.training import TrainConfig, train

    config = TrainConfig(name="threads", env=AllocConfig(**SMALL), threads=1,
                         td3={"n_timesteps": 40, "learning_starts": 20, "batch_size": 16,
                              "policy_kwargs": {"net_arch": [32, 32]}},
                         eval={"freq": 40, "episodes": 1}, checkpoint_freq=40,
                         service={"mode": "local", "store": str(tmp_path / "s.sqlite")})
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        metrics = train(config, tmp_path / "run", show_progress=False)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    assert metrics["timesteps"] == 40 and 0 < metrics["update_seconds"] < metrics["wall_seconds"]
    assert TD3.load(tmp_path / "run" / "model.zip", device="cpu").num_timesteps == 40


def test_saved_config_round_trips_nulls(tmp_path):
    """config.yaml keeps explicit nulls: a v2 env without an exit stays without one, and
    `threads: null` stays torch's choice."""
    import json

    import yaml

    from farm.alloc.training import TrainConfig, load_train_config

    config = TrainConfig(name="nulls", env=AllocConfig(exit_point=None), threads=None)
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(json.loads(config.model_dump_json()), sort_keys=False))
    again = load_train_config(path)
    assert again == config and again.env.exit_point is None and again.threads is None
    assert again.env.game_settings().key(2, 2).digest() == config.env.game_settings().key(2, 2).digest()


def test_the_training_curve_is_the_same_on_every_run(tmp_path):
    """The periodic evaluation's episodes are seeded from the config's seed (SB3's EvalCallback
    resets without one): two runs of one config write the same evaluations.npz."""
    from farm.alloc.training import TrainConfig, train

    config = TrainConfig(name="curve", env=AllocConfig(**SMALL), threads=1,
                         td3={"n_timesteps": 60, "learning_starts": 20, "batch_size": 16,
                              "policy_kwargs": {"net_arch": [32, 32]}},
                         eval={"freq": 20, "episodes": 3}, checkpoint_freq=60,
                         service={"mode": "local", "store": str(tmp_path / "s.sqlite")})
    curves = []
    for k in range(2):
        train(config, tmp_path / f"run{k}", show_progress=False)
        curves.append(np.load(tmp_path / f"run{k}" / "evaluations.npz")["results"])
    np.testing.assert_array_equal(curves[0], curves[1])
