"""A pretraining's saved state, trusted only when it is whole and its own
(farm.alloc.training.dagger.iterations), and its figures kept with the run's state
(farm.alloc.training.state.RunState), in process (service.mode local), no Ray.

- An iteration file with a byte flipped inside, a stale one (iteration 0's state under iteration
  2's name), another run's, one without a checksum, and one whose state misses a key or holds an
  empty policy are each moved to pretrain/damaged/ in one line; the resumed pretraining goes on
  from the whole one before and ends bit-identical to the uninterrupted one.
- A pretrained run (TD3, PPO) stopped after its first RL checkpoint and resumed has the
  pretraining's figures in metrics.json, equal to the uninterrupted run's.

The pretrainings are tiny: 3 iterations of 2 episodes of a 3x3 map, 2 epochs; the runs 200 steps.
"""

import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import Stop, stop_at

from farm.alloc.training import TrainConfig

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3, team_sizes="lattice")
PRETRAIN = {"expert": "intercept", "iterations": 3, "episodes": 2, "epochs": 2, "batch_size": 16,
            "episodes_per_task": 2}


def config(store: Path, algo: str = "td3", seed: int = 0) -> TrainConfig:
    section = {"td3": {"n_timesteps": 200, "learning_starts": 60, "batch_size": 32, "buffer_size": 1000},
               "ppo": {"n_timesteps": 192, "n_steps": 32, "batch_size": 16, "n_epochs": 2}}[algo]
    return TrainConfig(name=f"files-{algo}", seed=seed, env=SMALL, algo=algo, **{algo: section},
                       pretrain=PRETRAIN, eval={"freq": 100, "episodes": 2}, checkpoint_freq=96,
                       service={"mode": "local", "store": str(store)})


@pytest.fixture(scope="module")
def client(store):
    from farm.service import CaptureTimeClient

    c = CaptureTimeClient(config(store).env.game_settings(), local_store=store)
    yield c
    c.close()


def pretrained(cfg: TrainConfig, client, run_dir: Path):
    """(the pretrained model's policy state, pretrain's outcome) of a new model of cfg pretrained
    into run_dir (going on from what run_dir holds)."""
    from farm.alloc.training.dagger.loop import pretrain
    from farm.alloc.training.train import make_model, training_envs

    env, _, _ = training_envs(cfg, client)
    model = make_model(cfg, env, run_dir)
    done = pretrain(model, cfg, client, run_dir, show_progress=False)
    return {k: v.clone() for k, v in model.policy.state_dict().items()}, done


@pytest.fixture(scope="module")
def whole(store, client, tmp_path_factory):
    """The uninterrupted pretraining: its run folder, policy and outcome."""
    run = tmp_path_factory.mktemp("whole") / "run"
    policy, done = pretrained(config(store), client, run)
    return run, policy, done


def copy_of(whole_run: Path, tmp_path: Path) -> Path:
    """A run folder holding the uninterrupted pretraining's iteration files."""
    run = tmp_path / "run"
    shutil.copytree(whole_run / "pretrain", run / "pretrain")
    return run


def iteration(run: Path, k: int) -> Path:
    return run / "pretrain" / f"iteration_{k}.pkl"


def flip_a_byte(path: Path) -> None:
    """A byte flipped two thirds of the way into the file: inside the labels' arrays."""
    data = bytearray(path.read_bytes())
    data[2 * len(data) // 3] ^= 0x01
    path.write_bytes(bytes(data))


def assert_same_pretraining(whole, policy, done) -> None:
    _, whole_policy, whole_done = whole
    assert policy.keys() == whole_policy.keys()
    assert all(torch.equal(policy[k], whole_policy[k]) for k in policy)
    assert done.data.keys() == whole_done.data.keys()
    for name in done.data:
        np.testing.assert_array_equal(done.data[name], whole_done.data[name])
    assert (done.states, done.loss) == (whole_done.states, whole_done.loss)


def resumed(store, client, run: Path, capsys, then: str, *problems: tuple[int, str]):
    """Pretrain again into run; every damaged file is one line on stderr, moved aside."""
    capsys.readouterr()
    policy, done = pretrained(config(store), client, run)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == len(problems), lines
    for line, (k, problem) in zip(lines, problems):
        assert f"pretrain/iteration_{k}.pkl {problem}" in line, line
        assert line.endswith(f"; moved to pretrain/damaged/, {then}"), line
    assert sorted(p.name for p in (run / "pretrain" / "damaged").iterdir()) == sorted(
        f"iteration_{k}.pkl" for k, _ in problems)
    return policy, done


# ----- class 1: an iteration file is trusted only when whole and its own ------------------------

def test_a_flipped_byte_is_moved_aside_and_the_pretraining_goes_on_from_the_one_before(store, client, whole,
                                                                                       tmp_path, capsys):
    run = copy_of(whole[0], tmp_path)
    flip_a_byte(iteration(run, 2))
    policy, done = resumed(store, client, run, capsys, "resumed after iteration 1", (2, "is damaged"))
    assert done.resumed_after == 1
    assert_same_pretraining(whole, policy, done)


def test_a_stale_iteration_file_is_moved_aside(store, client, whole, tmp_path, capsys):
    """Iteration 0's state under iteration 2's name (a copy left over, a file restored wrongly)."""
    run = copy_of(whole[0], tmp_path)
    shutil.copyfile(iteration(run, 0), iteration(run, 2))
    policy, done = resumed(store, client, run, capsys, "resumed after iteration 1",
                           (2, "holds iteration 0's state, not iteration 2's"))
    assert done.resumed_after == 1
    assert_same_pretraining(whole, policy, done)


def test_another_runs_iteration_file_is_moved_aside(store, client, whole, tmp_path, capsys):
    """Iteration 2 of a pretraining of another seed, under this run's name."""
    other = tmp_path / "other"
    pretrained(config(store, seed=1), client, other)
    run = copy_of(whole[0], tmp_path)
    shutil.copyfile(iteration(other, 2), iteration(run, 2))
    policy, done = resumed(store, client, run, capsys, "resumed after iteration 1", (2, "is another run's"))
    assert_same_pretraining(whole, policy, done)


def test_an_iteration_file_missing_a_key_is_moved_aside_not_a_traceback(store, client, whole, tmp_path, capsys):
    """A plain pickle of an iteration's state without its policy: a file without a checksum is not
    read (a flipped byte in its arrays could not be seen), so the pretraining starts again."""
    run = copy_of(whole[0], tmp_path)
    for k in (0, 1, 2):
        iteration(run, k).unlink()
    whole_done = whole[2]
    iteration(run, 1).write_bytes(pickle.dumps({"iteration": 1, "data": whole_done.data, "rng": None,
                                                "seconds": 1.0, "loss": 0.5}))
    policy, done = resumed(store, client, run, capsys, "the pretraining starts again", (1, "has no checksum"))
    assert done.resumed_after is None
    assert_same_pretraining(whole, policy, done)


@pytest.mark.parametrize("change", [{"policy": {}}, {"policy": None}, {"data": {"obs": np.zeros((3, 18))}},
                                    {"rng": {"bit_generator": "PCG64", "state": "x"}}])
def test_a_whole_iteration_file_of_a_bad_state_is_moved_aside(store, client, whole, tmp_path, capsys, change):
    """Checksum and header right (written by write_iteration), the state inside not this run's."""
    from farm.alloc.training.dagger.iterations import read_iteration, run_digest, write_iteration

    run = copy_of(whole[0], tmp_path)
    digest = run_digest(config(store))
    state = read_iteration(iteration(run, 2), 2, digest)
    write_iteration(run, {**state, **change}, digest)
    policy, done = resumed(store, client, run, capsys, "resumed after iteration 1", (2, "is damaged"))
    assert_same_pretraining(whole, policy, done)


def test_every_iteration_damaged_starts_the_pretraining_again_as_exact(store, client, whole, tmp_path, capsys):
    run = copy_of(whole[0], tmp_path)
    for k in (0, 1, 2):
        flip_a_byte(iteration(run, k))
    policy, done = resumed(store, client, run, capsys, "the pretraining starts again",
                           *[(k, "is damaged") for k in (2, 1, 0)])
    assert done.resumed_after is None
    assert_same_pretraining(whole, policy, done)


# ----- class 2: the pretraining's figures survive a resume from an RL checkpoint ------------------

FIGURES = ("pretrain_states", "pretrain_loss", "pretrained_eval_mean_return", "pretrain_resumed_after")


@pytest.mark.parametrize("algo", ["td3", "ppo"])
def test_a_run_resumed_after_its_first_checkpoint_keeps_the_pretrainings_figures(store, tmp_path, algo):
    from farm.alloc.training import train

    cfg = config(store, algo)
    uninterrupted = train(cfg, tmp_path / "whole", show_progress=False)
    assert all(uninterrupted[k] is not None for k in FIGURES if k != "pretrain_resumed_after")
    with pytest.raises(Stop):
        train(cfg, tmp_path / "stopped", show_progress=False, callbacks=[stop_at(120)])
    assert (tmp_path / "stopped" / "checkpoints").is_dir() and not (tmp_path / "stopped" / "metrics.json").exists()
    metrics = train(cfg, tmp_path / "stopped", resume=True, show_progress=False)
    assert metrics["resumed_from"] == 96
    assert {k: metrics[k] for k in FIGURES} == {k: uninterrupted[k] for k in FIGURES}
    assert metrics["pretrain_seconds"] is not None and metrics["pretrain_seconds"] > 0
    written = json.loads((tmp_path / "stopped" / "metrics.json").read_text())
    assert {k: written[k] for k in FIGURES} == {k: uninterrupted[k] for k in FIGURES}
