"""CellPolicy (farm.alloc.networks.cell_policy): PPO's actor-critic shared by every cell.

- Each action entry is the score its cell gives that move: the gather from (move, cell)
  scores puts every (d_row, d_col) of every cell where farm.alloc.game.dynamics.moves has it.
- Its weights do not depend on the map's size (but PPO's log_std, one per action entry).
- It trains, saves and loads as PPO's own policies do, it is fitted by the pretraining, and a
  bad policy_kwargs is one line naming the field.
"""

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from farm.alloc.game.dynamics import moves, n_actions
from farm.alloc.training import TrainConfig, train
from farm.alloc.networks.cell_policy import CellNet
from helpers import Stop, assert_same_policy, stop_at
from test_learners import assert_refused_in_one_line

REPO = Path(__file__).resolve().parents[1]
SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3, team_sizes="lattice")


@pytest.mark.parametrize("n", [2, 3, 5, 8])
def test_every_action_entry_is_its_cells_score_of_that_move(n):
    net = CellNet(n, channels=4, layers=1)
    scores = torch.zeros(1, 9, n, n)
    for k in range(9):
        scores[0, k] = 1000 * k + torch.arange(n * n, dtype=torch.float32).reshape(n, n)
    gathered = scores.flatten(1)[:, net.index][0].numpy().astype(int)
    move, cell = gathered // 1000, gathered % 1000
    src, dst, _ = moves(n)
    assert len(gathered) == n_actions(n)
    np.testing.assert_array_equal(cell, src)
    d_row, d_col = move // 3 - 1, move % 3 - 1
    np.testing.assert_array_equal((src // n + d_row) * n + src % n + d_col, dst)


def test_its_weights_do_not_depend_on_the_map_size():
    counts = {n: sum(p.numel() for p in CellNet(n, channels=8, layers=2).parameters()) for n in (3, 5, 8, 16)}
    assert len(set(counts.values())) == 1, counts
    small, large = CellNet(3, 8, 2), CellNet(8, 8, 2)
    large.load_state_dict(small.state_dict())  # the same tensors fit any size


def config(store, **changes) -> TrainConfig:
    raw = {"name": "tiny-cells", "seed": 0, "env": SMALL, "algo": "ppo",
           "ppo": {"n_timesteps": 256, "n_steps": 64, "batch_size": 64, "n_epochs": 2, "policy": "CellPolicy",
                   "policy_kwargs": {"channels": 8, "layers": 2}},
           "eval": {"freq": 128, "episodes": 2}, "checkpoint_freq": 128,
           "service": {"mode": "local", "store": str(store)}}
    raw.update(changes)
    return TrainConfig(**raw)


def test_it_trains_resumes_and_loads_as_ppos_policies_do(tmp_path):
    from farm.alloc.allocators.learned import load_model

    cfg = config(tmp_path / "s.sqlite", n_envs=2,
                 pretrain={"expert": "intercept", "iterations": 2, "episodes": 4, "epochs": 5})
    metrics = train(cfg, tmp_path / "whole", show_progress=False)
    assert metrics["pretrain_states"] > 0 and metrics["timesteps"] >= 256
    model = load_model(tmp_path / "whole", "ppo")
    assert type(model.policy).__name__ == "CellPolicy"
    obs = np.random.default_rng(0).uniform(0, 0.3, (4, 18)).astype(np.float32)
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (4, n_actions(3))

    with pytest.raises(Stop):
        train(cfg, tmp_path / "stopped", show_progress=False, callbacks=[stop_at(130)])
    train(cfg, tmp_path / "stopped", show_progress=False, resume=True)
    assert_same_policy(tmp_path / "whole" / "model.zip", tmp_path / "stopped" / "model.zip", "ppo")


@pytest.mark.parametrize("changes, field", [
    ({"policy_kwargs": {"net_arch": [64]}}, "net_arch"),
    ({"policy_kwargs": {"channels": 0}}, "channels"),
    ({"policy_kwargs": {"layers": 1.5}}, "layers"),
    ({"policy": "CnnPolicy"}, "ppo.policy"),
])
def test_a_bad_cell_policy_setting_is_one_line_naming_the_field(tmp_path, changes, field):
    raw = yaml.safe_load((REPO / "configs" / "train" / "tiny.yaml").read_text())
    raw["algo"] = "ppo"
    raw["ppo"] = {"n_timesteps": 256, "policy": "CellPolicy", **changes}
    assert_refused_in_one_line(tmp_path, raw, field)
