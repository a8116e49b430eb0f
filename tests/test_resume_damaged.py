"""`--resume` from a damaged checkpoint (farm.alloc.training.train, farm.alloc.training.runs:
whole_checkpoints, move_damaged): a newest checkpoint whose model zip is cut short or has a bad
CRC, whose replay buffer is garbage or whose RunState is cut short is moved to
checkpoints/damaged/, said in one line, and the run goes on from the checkpoint before it,
ending bit-identical to the uninterrupted run (the same weights and optimisers,
evaluations.npz and metrics.json but the timings); with every checkpoint damaged, `farm train
--resume` is one line, exit 2. A damaged pretraining iteration (pretrain/iteration_<i>.pkl)
goes on from the one before, or pretrains again, as exact. In process (service.mode local), no Ray.

One tiny pretrained TD3 run (conftest.train_tiny_run: 120 steps, checkpoints at 40, 80 and
120) is the uninterrupted reference; each test damages a copy of it and resumes the copy."""

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import farm_main, train_tiny_run
from test_train_resume import TIMINGS, assert_same_model

EXTRA = ("checkpoint_freq: 40\neval: {freq: 40, episodes: 2}\n"
         "pretrain: {expert: intercept, iterations: 2, episodes: 2, epochs: 2, batch_size: 16, episodes_per_task: 2}\n")
LAST, BEFORE = 120, 80  # the reference's last checkpoint and the one before it


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The uninterrupted run's folder (its config is ../tiny.yaml)."""
    return train_tiny_run(tmp_path_factory.mktemp("damaged"), EXTRA)


def copy_of(reference: Path, tmp_path: Path) -> Path:
    """A copy of the reference run without its final model (the resume writes it again)."""
    run = tmp_path / "run"
    shutil.copytree(reference, run)
    (run / "model.zip").unlink()
    return run


def resume(reference: Path, run: Path, *more):
    return farm_main("train", reference.parent / "tiny.yaml", "--out", run, "--resume", *more)


def cut_short(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def flip_a_byte(path: Path) -> None:
    """A byte flipped in the middle of the model zip's policy.pth: the member's CRC fails."""
    with zipfile.ZipFile(path) as z:
        member = z.getinfo("policy.pth")
    data = bytearray(path.read_bytes())
    at = member.header_offset + 30 + len(member.filename) + len(member.extra) + member.compress_size // 2
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))


def garbage(path: Path) -> None:
    path.write_bytes(b"not a pickle, only bytes\x00\xff" * 10)


DAMAGES = {  # the damage: (which of checkpoint_files, how, the damaged file's problem)
    "a model zip cut short": (0, cut_short, "fails its checksum"),
    "a model zip with a bad CRC": (0, flip_a_byte, "fails its checksum"),
    "a garbage replay buffer": (1, garbage, "fails its checksum"),
    "a RunState cut short": (2, cut_short, "fails its checksum"),
}


def assert_same_run(a: Path, b: Path, *also_left_out: str) -> None:
    """Runs a and b trained the same: model.zip's weights and optimisers, evaluations.npz and
    metrics.json but the timings, resumed_from and also_left_out."""
    assert_same_model(a / "model.zip", b / "model.zip")
    ea, eb = np.load(a / "evaluations.npz"), np.load(b / "evaluations.npz")
    assert ea.files == eb.files and all(np.array_equal(ea[k], eb[k]) for k in ea.files)
    assert ea["timesteps"].tolist() == [0, 40, 80, 120]  # the pretrained model's first
    ma, mb = (json.loads((run / "metrics.json").read_text()) for run in (a, b))
    for name in ("resumed_from", *TIMINGS, *also_left_out):
        ma.pop(name), mb.pop(name)
    assert ma == mb


@pytest.mark.parametrize("damage", DAMAGES)
def test_a_damaged_last_checkpoint_is_moved_aside_and_the_run_goes_on_from_the_one_before(reference, tmp_path,
                                                                                          damage):
    from farm.alloc.training.runs import checkpoint_files

    which, how, error = DAMAGES[damage]
    run = copy_of(reference, tmp_path)
    damaged = checkpoint_files(run, LAST)
    how(damaged[which])
    sizes = {p.name: p.stat().st_size for p in damaged}
    status, out, err = resume(reference, run, "--quiet")
    assert status == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert f"the checkpoint of {LAST} steps is damaged ({damaged[which].name}: {error})" in lines[0]
    assert f"moved to checkpoints/damaged/, resumed from the checkpoint of {BEFORE} steps" in lines[0]
    aside = run / "checkpoints" / "damaged"
    assert {p.name: p.stat().st_size for p in aside.iterdir()} == sizes  # the three files, as they were
    assert json.loads((run / "metrics.json").read_text())["resumed_from"] == BEFORE
    assert_same_run(reference, run)
    assert all(p.exists() for p in checkpoint_files(run, LAST))  # the resumed run's own, written again


def test_every_checkpoint_damaged_is_one_line_through_the_cli(reference, tmp_path):
    from farm.alloc.training.runs import checkpoint_files

    run = copy_of(reference, tmp_path)
    for steps in (40, BEFORE, LAST):
        cut_short(checkpoint_files(run, steps)[0])
    status, out, err = resume(reference, run)
    assert status == 2, err
    line = err.strip()
    assert "\n" not in line and "Traceback" not in line, err
    assert line == (f"farm: error: --resume: {run} has no whole checkpoint (3 damaged, moved to "
                    f"checkpoints/damaged/); train it again into another folder")
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["damaged"]
    assert len(list((run / "checkpoints" / "damaged").iterdir())) == 9
    assert not (run / "model.zip").exists()


@pytest.mark.parametrize("damaged, then", [((1,), "resumed after iteration 0"),
                                           ((1, 0), "the pretraining starts again")])
def test_a_damaged_pretraining_iteration_goes_on_from_the_one_before(reference, tmp_path, damaged, then):
    """A run stopped in its pretraining (no checkpoint yet) whose last iteration files are damaged."""
    from farm.alloc.training.dagger.loop import iteration_file

    run = copy_of(reference, tmp_path)
    shutil.rmtree(run / "checkpoints")
    for i in damaged:
        cut_short(iteration_file(run, i))
    status, out, err = resume(reference, run, "--quiet")
    assert status == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == len(damaged), err
    for i, line in zip(damaged, lines):
        assert f"pretrain/iteration_{i}.pkl is damaged (fails its checksum); moved to pretrain/damaged/, {then}" in line
    assert sorted(p.name for p in (run / "pretrain" / "damaged").iterdir()) == sorted(
        f"iteration_{i}.pkl" for i in damaged)
    resumed_after = json.loads((run / "metrics.json").read_text())["pretrain_resumed_after"]
    assert resumed_after == (None if 0 in damaged else 0)
    assert_same_run(reference, run, "pretrain_seconds", "pretrain_resumed_after")


def test_whole_checkpoints_are_newest_first_and_latest_checkpoint_is_the_first(tmp_path):
    from farm.alloc.training.runs import checkpoint_files, latest_checkpoint, move_damaged, whole_checkpoints

    assert whole_checkpoints(tmp_path) == [] and latest_checkpoint(tmp_path) is None
    for steps, files in ((100, 3), (300, 3), (200, 3), (400, 2)):  # 400: stopped before its state was written
        for f in checkpoint_files(tmp_path, steps)[:files]:
            f.parent.mkdir(exist_ok=True)
            f.write_bytes(b"")
    assert whole_checkpoints(tmp_path) == [300, 200, 100]
    assert latest_checkpoint(tmp_path) == (checkpoint_files(tmp_path, 300)[0], 300)
    checkpoint_files(tmp_path, 300)[1].unlink()  # no replay buffer: whole for PPO alone
    assert whole_checkpoints(tmp_path) == [200, 100] and whole_checkpoints(tmp_path, replay_buffer=False)[0] == 300
    folder = move_damaged(*checkpoint_files(tmp_path, 200))
    assert folder == tmp_path / "checkpoints" / "damaged" and whole_checkpoints(tmp_path) == [100]
    checkpoint_files(tmp_path, 200)[2].write_bytes(b"again")
    move_damaged(checkpoint_files(tmp_path, 200)[2])  # a name taken in damaged/: the earlier file is kept
    names = sorted(p.name for p in folder.iterdir())
    assert len(names) == 4 and names[-1].startswith("rl_model_state_200_steps.pkl.")
