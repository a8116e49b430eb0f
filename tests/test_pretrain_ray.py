"""Pretraining's labels on the farm (issue 25): with `service.mode: ray` the episodes are
played and labelled in Ray tasks, a batch of episodes each, and the data set, the fitted policy
and the trained model are the same as in process, whatever the tasks' size."""


import numpy as np
import pytest
import torch

from farm.alloc.training import TrainConfig, train
from farm.alloc.training.dagger.iterations import iteration_file, read_iteration

pytestmark = [pytest.mark.ray, pytest.mark.slow]

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3, team_sizes="lattice")


def config(store, mode: str, per_task: int) -> TrainConfig:
    return TrainConfig(name="tiny-ppo", seed=0, env=SMALL, algo="ppo",
                       ppo={"n_timesteps": 128, "n_steps": 64, "batch_size": 32, "n_epochs": 2},
                       pretrain={"expert": "receding_horizon", "iterations": 2, "episodes": 6, "epochs": 3,
                                 "episodes_per_task": per_task},
                       eval={"freq": 64, "episodes": 2}, checkpoint_freq=64,
                       service={"mode": mode, "store": str(store)})


def test_labels_on_ray_tasks_equal_labels_in_process(ray_local, tmp_path):
    store = tmp_path / "store.sqlite"
    train(config(store, "local", 6), tmp_path / "local", show_progress=False)
    train(config(store, "ray", 2), tmp_path / "ray", show_progress=False)  # 3 tasks an iteration on 2 CPUs
    for k in range(2):
        a = read_iteration(iteration_file(tmp_path / "local", k))
        b = read_iteration(iteration_file(tmp_path / "ray", k))
        assert len(a["data"]["obs"]) == len(b["data"]["obs"]) > 0
        for name in a["data"]:
            np.testing.assert_array_equal(a["data"][name], b["data"][name])
        assert all(torch.equal(a["policy"][p], b["policy"][p]) for p in a["policy"])
