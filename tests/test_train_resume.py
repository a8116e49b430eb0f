"""A resumed training equals an uninterrupted one (farm.alloc.training: Checkpointer, RunState,
SwarmAllocationEnv.get_state): the same weights, optimiser states, replay buffer,
evaluations.npz, best/ model and metrics, whether the run was stopped after a checkpoint or
trained shorter and then resumed to the full length. In process (`service.mode: local`), no Ray."""

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from helpers import Stop, stop_at

from farm.core.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
STEPS, CHECKPOINT_FREQ, EVAL_FREQ, LEARNING_STARTS = 300, 70, 50, 100
TIMINGS = ("wall_seconds", "steps_per_second", "update_seconds", "outside_update_share")


def tiny(store: Path, **td3):
    """configs/train/tiny.yaml on the team-size lattice (35 cases, computed at the start), in
    process on `store`: checkpoints every 70 steps (not a multiple of the evaluations' 50, so a
    resumed run must evaluate at the steps an uninterrupted one does), td3 fields replaced."""
    from farm.alloc.training import TrainConfig

    raw = yaml.safe_load((ROOT / "configs" / "train" / "tiny.yaml").read_text())
    raw["env"]["team_sizes"] = "lattice"
    raw["td3"].update(n_timesteps=STEPS, learning_starts=LEARNING_STARTS, **td3)
    raw.update(eval={"freq": EVAL_FREQ, "episodes": 3}, checkpoint_freq=CHECKPOINT_FREQ,
               service={"mode": "local", "store": str(store)})
    return TrainConfig(**raw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run: (its folder, its config)."""
    from farm.alloc.training import train

    tmp = tmp_path_factory.mktemp("resume")
    config = tiny(tmp / "store.sqlite")
    train(config, tmp / "uninterrupted", show_progress=False)
    return tmp / "uninterrupted", config


def model_tensors(path: Path) -> dict:
    """Every tensor of a saved model: the policy's (actor, critics, their targets) and both optimisers' states."""
    from stable_baselines3 import TD3

    model = TD3.load(path, device="cpu")
    tensors = {f"policy.{k}": v for k, v in model.policy.state_dict().items()}
    for name in ("actor", "critic"):
        for i, state in getattr(model, name).optimizer.state_dict()["state"].items():
            tensors.update({f"{name}.optimizer.{i}.{k}": torch.as_tensor(v) for k, v in state.items()})
    return tensors


def assert_same_model(a: Path, b: Path) -> None:
    ta, tb = model_tensors(a), model_tensors(b)
    assert ta.keys() == tb.keys()
    different = [k for k in ta if not torch.equal(ta[k], tb[k])]
    assert not different, f"{b} differs from {a} in {different[:3]}"


def assert_same_run(a: Path, b: Path) -> None:
    """Runs a and b trained the same: weights and optimisers, the last checkpoint's replay
    buffer, evaluations.npz, best/ and metrics.json but for the timings and resumed_from."""
    assert_same_model(a / "model.zip", b / "model.zip")
    assert_same_model(a / "best" / "best_model.zip", b / "best" / "best_model.zip")
    last = STEPS // CHECKPOINT_FREQ * CHECKPOINT_FREQ
    buffers = [pickle.loads((run / "checkpoints" / f"rl_model_replay_buffer_{last}_steps.pkl").read_bytes())
               for run in (a, b)]
    for field in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts", "pos"):
        assert np.array_equal(getattr(buffers[0], field), getattr(buffers[1], field)), field
    ea, eb = np.load(a / "evaluations.npz"), np.load(b / "evaluations.npz")
    assert ea.files == eb.files and all(np.array_equal(ea[k], eb[k]) for k in ea.files)
    assert ea["timesteps"].tolist() == list(range(EVAL_FREQ, STEPS + 1, EVAL_FREQ))
    ma, mb = (json.loads((run / "metrics.json").read_text()) for run in (a, b))
    for name in ("resumed_from", *TIMINGS):
        ma.pop(name), mb.pop(name)
    assert ma == mb


@pytest.mark.slow
def test_a_run_stopped_after_a_checkpoint_and_resumed_equals_an_uninterrupted_one(reference, tmp_path):
    """Stopped at step 260: after the checkpoint of step 210 (past learning_starts, so the
    update's random draws matter) and the evaluation of step 250, which the resumed run redoes."""
    from farm.alloc.training import train
    from farm.alloc.training.runs import checkpoint_files, latest_checkpoint

    uninterrupted, config = reference
    run = tmp_path / "run"
    with pytest.raises(Stop):
        train(config, run, show_progress=False, callbacks=[stop_at(260)])
    assert latest_checkpoint(run)[1] == 210
    assert np.load(run / "evaluations.npz")["timesteps"].tolist() == [50, 100, 150, 200, 250]
    metrics = train(config, run, resume=True, show_progress=False)
    assert metrics["resumed_from"] == 210 and metrics["timesteps"] == STEPS
    assert_same_run(uninterrupted, run)
    from farm.alloc.training.runs import STATE_MAGIC
    from farm.core.sealed import unseal

    earlier = pickle.loads(unseal(checkpoint_files(run, 210)[2].read_bytes(), STATE_MAGIC)[1])  # the timings go on
    assert metrics["wall_seconds"] > earlier["wall_seconds"] > 0
    assert metrics["update_seconds"] > earlier["update_seconds"]


@pytest.mark.slow
def test_a_shorter_run_resumed_to_the_full_length_equals_an_uninterrupted_one(reference, tmp_path):
    """Trained 70 steps (before learning_starts: the warm-up's random actions come from the
    action space's generator), then resumed to 300."""
    from farm.alloc.training import train

    uninterrupted, config = reference
    run = tmp_path / "run"
    short = config.model_copy(update={"td3": config.td3.model_copy(update={"n_timesteps": CHECKPOINT_FREQ})})
    assert train(short, run, show_progress=False)["timesteps"] == CHECKPOINT_FREQ
    assert train(config, run, resume=True, show_progress=False)["resumed_from"] == CHECKPOINT_FREQ
    assert_same_run(uninterrupted, run)


def test_latest_checkpoint_is_the_last_whole_one(tmp_path):
    """A checkpoint counts once its RunState file (written last) is there."""
    from farm.alloc.training.runs import checkpoint_files, latest_checkpoint

    assert latest_checkpoint(tmp_path) is None
    for steps, files in ((100, 3), (200, 3), (300, 2)):  # 300: stopped before its state was written
        for f in checkpoint_files(tmp_path, steps)[:files]:
            f.parent.mkdir(exist_ok=True)
            f.write_bytes(b"")
    assert latest_checkpoint(tmp_path) == (tmp_path / "checkpoints" / "rl_model_200_steps.zip", 200)
    checkpoint_files(tmp_path, 200)[1].unlink()
    assert latest_checkpoint(tmp_path)[1] == 100


@pytest.mark.slow
def test_the_env_goes_on_from_its_state(reference):
    """get_state mid-episode, set_state in another env: the same steps and the same next
    episode's start; a state of another grid is refused in one line."""
    from farm.alloc.envs.defenders import SwarmAllocationEnv

    _, config = reference  # its store holds the lattice's cases
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1, 1, (2 * config.env.max_steps, 49))
    with SwarmAllocationEnv(config.env, store=config.service.store) as a, \
            SwarmAllocationEnv(config.env, store=config.service.store) as b:
        a.reset(seed=7)
        for action in actions[:3]:
            a.step(action)
        state = a.get_state()
        b.set_state(pickle.loads(pickle.dumps(state)))
        assert b.engagements == a.engagements > 0
        for action in actions[3:]:
            out_a, out_b = a.step(action), b.step(action)
            assert np.array_equal(out_a[0], out_b[0]) and out_a[1:4] == out_b[1:4]
            if out_a[2] or out_a[3]:
                break
        assert np.array_equal(a.reset()[0], b.reset()[0])  # the generator went on the same
    with SwarmAllocationEnv(config.env.model_copy(update={"grid_size": 4}), client=object()) as other:
        with pytest.raises(ConfigError, match="set_state: the state's densities are of shape") as e:
            other.set_state(state)
    assert "\n" not in str(e.value)


@pytest.mark.slow
def test_a_resumed_intruders_run_equals_an_uninterrupted_one(reference, tmp_path):
    """The same for the intruders' side (side: intruders, the intruders' env against a frozen
    allocator): stopped at step 260, after the checkpoint of step 210, and resumed."""
    from farm.alloc.training import train

    _, defenders = reference  # its store holds the lattice's cases
    config = defenders.model_copy(update={"side": "intruders", "opponent": defenders.opponent.model_copy(
        update={"name": "greedy_nearest", "reward": "zero_sum"})})
    train(config, tmp_path / "uninterrupted", show_progress=False)
    with pytest.raises(Stop):
        train(config, tmp_path / "run", show_progress=False, callbacks=[stop_at(260)])
    assert train(config, tmp_path / "run", resume=True, show_progress=False)["resumed_from"] == 210
    assert_same_run(tmp_path / "uninterrupted", tmp_path / "run")
    assert yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["side"] == "intruders"
