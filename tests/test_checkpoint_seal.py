"""A checkpoint's RunState is sealed (farm.core.sealed) with the SHA-256 of its model and replay
buffer: a byte flipped inside the replay buffer's arrays or the RunState's, which still
unpickle, is found before anything is loaded, the checkpoint moved to checkpoints/damaged/ in one
line, and the run goes on from the one before, ending bit-identical to the uninterrupted run. A
RunState written without a seal is read as before. In process (service.mode local), no Ray; a
tiny TD3 run of 200 steps, checkpoints at 64, 128 and 192."""

import shutil
from pathlib import Path

import pytest
from test_train_resume import assert_same_model

from farm.alloc.training import TrainConfig

LAST, BEFORE = 192, 128


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    from farm.alloc.training import train

    root = tmp_path_factory.mktemp("seal")
    config = TrainConfig(name="seal", seed=0, env={"grid_size": 3, "n_defenders": 10, "n_intruders": 5, "games": 3},
                         td3={"n_timesteps": 200, "learning_starts": 50, "batch_size": 32, "buffer_size": 1000},
                         eval={"freq": 100, "episodes": 2}, checkpoint_freq=64,
                         service={"mode": "local", "store": str(root / "store.sqlite")})
    train(config, root / "run", show_progress=False)
    return root / "run", config


def copy_of(run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    (copy / "model.zip").unlink()
    return copy


def flip_a_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("which", [1, 2])  # the replay buffer, the RunState
def test_a_flipped_byte_in_a_checkpoint_is_found_and_the_run_goes_on_from_the_one_before(reference, tmp_path,
                                                                                        capsys, which):
    from farm.alloc.training import train
    from farm.alloc.training.runs import checkpoint_files

    run_dir, config = reference
    run = copy_of(run_dir, tmp_path)
    damaged = checkpoint_files(run, LAST)[which]
    flip_a_byte(damaged)
    capsys.readouterr()
    metrics = train(config, run, resume=True, show_progress=False)
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [f"train {run}: the checkpoint of {LAST} steps is damaged ({damaged.name}: fails its checksum); "
                     f"moved to checkpoints/damaged/, resumed from the checkpoint of {BEFORE} steps"]
    assert metrics["resumed_from"] == BEFORE
    assert_same_model(run_dir / "model.zip", run / "model.zip")


def test_a_runstate_without_a_seal_is_read_as_before(reference, tmp_path):
    """The last checkpoint's RunState rewritten as a plain pickle: resumed from it, as exact."""
    from farm.alloc.training import train
    from farm.alloc.training.runs import STATE_MAGIC, checkpoint_files
    from farm.core.sealed import unseal

    run_dir, config = reference
    run = copy_of(run_dir, tmp_path)
    state = checkpoint_files(run, LAST)[2]
    state.write_bytes(bytes(unseal(state.read_bytes(), STATE_MAGIC)[1]))
    metrics = train(config, run, resume=True, show_progress=False)
    assert metrics["resumed_from"] == LAST
    assert_same_model(run_dir / "model.zip", run / "model.zip")
