"""An experiment's storage (farm/studies/experiments/storage.py) without Ray: a trial's run
folder written again from its Tune checkpoint (or kept when it is as recent), the checkpoint's
copy of a run folder, and an experiment in an S3 bucket (moto's server on localhost) refusing
what a local folder refuses, in one line."""

import json
import shutil
from pathlib import Path

import pytest
from conftest import bucket_keys, s3_bucket

from farm.core.errors import ConfigError
from farm.studies.experiments.storage import ExperimentStorage, checkpoint_run, restore_run

ROOT = Path(__file__).resolve().parent.parent


def fake_run(path: Path, steps: list[int], replay_buffer: bool = True) -> Path:
    """A run folder whose files are named as a training run's (contents: their names), with
    whole checkpoints at `steps`."""
    from farm.alloc.training.runs import checkpoint_files

    (path / "best").mkdir(parents=True)
    for name in ("config.yaml", "evaluations.npz", "best/best_model.zip"):
        (path / name).write_text(name)
    for n in steps:
        model, buffer, state = checkpoint_files(path, n)
        model.parent.mkdir(exist_ok=True)
        for f in (model, state, *([buffer] if replay_buffer else [])):
            f.write_text(f"{f.name} of {path.name}")
    return path


def files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_text() for p in sorted(folder.rglob("*")) if p.is_file()}


def checkpoint_of(run: Path, steps: int, to: Path):
    from ray import tune

    to.mkdir()
    (to / "progress.json").write_text(json.dumps({"timesteps": steps}))
    checkpoint_run(run, steps, to)
    return tune.Checkpoint.from_directory(str(to))


def test_a_checkpoint_holds_the_run_folder_with_its_own_checkpoint_only(tmp_path):
    run = fake_run(tmp_path / "run", [100, 150])
    checkpoint_of(run, 150, tmp_path / "ck")
    held = files(tmp_path / "ck" / "run")
    assert sorted(k for k in held if k.startswith("checkpoints/")) == [
        "checkpoints/rl_model_150_steps.zip", "checkpoints/rl_model_replay_buffer_150_steps.pkl",
        "checkpoints/rl_model_state_150_steps.pkl"]
    assert {k: v for k, v in held.items() if not k.startswith("checkpoints/")} == {
        "best/best_model.zip": "best/best_model.zip", "config.yaml": "config.yaml",
        "evaluations.npz": "evaluations.npz"}


@pytest.mark.parametrize("local_steps, expected_steps, from_checkpoint", [
    (None, 150, True),     # no local folder (another node, or deleted): written from the checkpoint
    ([100], 150, True),    # an older local checkpoint: replaced by the checkpoint's folder
    ([150], 150, False),   # as recent: kept
    ([150, 200], 200, False),  # more recent: kept (resume is exact from either)
])
def test_a_trial_restores_its_run_folder_from_its_checkpoint_unless_it_holds_one_as_recent(
        tmp_path, local_steps, expected_steps, from_checkpoint):
    source = fake_run(tmp_path / "source", [150])
    checkpoint = checkpoint_of(source, 150, tmp_path / "ck")
    run = tmp_path / "trial" / "run"
    if local_steps is not None:
        fake_run(run, local_steps)
    before = files(run) if run.exists() else None
    assert restore_run(checkpoint, run, replay_buffer=True) == expected_steps
    assert files(run) == (files(tmp_path / "ck" / "run") if from_checkpoint else before)


def test_a_marker_checkpoint_of_before_0_6_leaves_the_run_folder_as_it_is(tmp_path):
    from ray import tune

    (tmp_path / "ck").mkdir()
    (tmp_path / "ck" / "progress.json").write_text(json.dumps({"timesteps": 150, "sb3_checkpoint": "x"}))
    run = fake_run(tmp_path / "run", [100])
    before = files(run)
    assert restore_run(tune.Checkpoint.from_directory(str(tmp_path / "ck")), run, replay_buffer=True) == 100
    assert files(run) == before
    assert restore_run(None, tmp_path / "none", replay_buffer=True) is None


def test_an_on_policy_run_restores_without_a_replay_buffer(tmp_path):
    source = fake_run(tmp_path / "source", [60], replay_buffer=False)
    run = tmp_path / "run"
    assert restore_run(checkpoint_of(source, 60, tmp_path / "ck"), run, replay_buffer=False) == 60
    assert not any("replay_buffer" in k for k in files(run))


def pretrained_run(path: Path, iterations: int, steps: list[int] = ()) -> Path:
    """fake_run with pretraining iterations 0 .. iterations-1 saved (pretrain/iteration_<i>.pkl)."""
    fake_run(path, list(steps), replay_buffer=False)
    (path / "pretrain").mkdir()
    for i in range(iterations):
        (path / "pretrain" / f"iteration_{i}.pkl").write_text(f"iteration {i} of {path.name}")
    return path


def pretrain_checkpoint_of(run: Path, iteration: int, to: Path):
    from ray import tune

    to.mkdir()
    (to / "progress.json").write_text(json.dumps({"timesteps": 0, "pretrain_iteration": iteration}))
    checkpoint_run(run, None, to)
    return tune.Checkpoint.from_directory(str(to))


def test_a_pretraining_checkpoint_holds_the_run_folder_with_its_newest_iteration_only(tmp_path):
    pretrain_checkpoint_of(pretrained_run(tmp_path / "run", 3), 2, tmp_path / "ck")
    held = files(tmp_path / "ck" / "run")
    assert held == {"best/best_model.zip": "best/best_model.zip", "config.yaml": "config.yaml",
                    "evaluations.npz": "evaluations.npz", "pretrain/iteration_2.pkl": "iteration 2 of run"}
    later = pretrained_run(tmp_path / "later", 3, steps=[64])  # training's checkpoints keep the newest iteration too
    checkpoint_of(later, 64, tmp_path / "ck64")
    pretraining = sorted(k for k in files(tmp_path / "ck64" / "run") if k.startswith("pretrain/"))
    assert pretraining == ["pretrain/iteration_2.pkl"]


@pytest.mark.parametrize("local, expected_steps, from_checkpoint", [
    (None, 0, True),            # no local folder: written from the pretraining checkpoint of iteration 1
    ((1, []), 0, True),         # only iteration 0 here: replaced
    ((2, []), 0, False),        # iteration 1 here: as far, kept
    ((3, []), 0, False),        # iteration 2 here: further, kept
    ((3, [64]), 64, False),     # training's checkpoint here: further than any pretraining, kept
])
def test_a_trial_restores_its_pretraining_from_its_checkpoint_unless_its_folder_is_as_far(
        tmp_path, local, expected_steps, from_checkpoint):
    checkpoint = pretrain_checkpoint_of(pretrained_run(tmp_path / "source", 2), 1, tmp_path / "ck")
    run = tmp_path / "trial" / "run"
    if local is not None:
        pretrained_run(run, *local)
    before = files(run) if run.exists() else None
    assert restore_run(checkpoint, run, replay_buffer=False) == expected_steps
    assert files(run) == (files(tmp_path / "ck" / "run") if from_checkpoint else before)


def test_a_training_checkpoint_replaces_a_folder_still_in_its_pretraining(tmp_path):
    source = pretrained_run(tmp_path / "source", 3, steps=[64])
    run = pretrained_run(tmp_path / "trial" / "run", 3)
    assert restore_run(checkpoint_of(source, 64, tmp_path / "ck"), run, replay_buffer=False) == 64
    assert files(run) == files(tmp_path / "ck" / "run")


@pytest.fixture(scope="module")
def s3():
    with s3_bucket("farm") as client:
        yield client


def test_an_experiment_in_a_bucket_refuses_another_experiment_and_foreign_files(s3):
    storage = ExperimentStorage("s3://farm/exp")
    storage.check_for("abc")  # nothing there yet
    storage.write_manifest({"name": "smoke", "digest": "abc", "trials": [], "fields": []})
    storage.check_for("abc")
    with pytest.raises(ConfigError, match=r"^out: s3://farm/exp holds another experiment \(smoke, config digest abc"):
        storage.check_for("def")
    s3.put_object(Bucket="farm", Key="other/notes.txt", Body=b"x")
    with pytest.raises(ConfigError, match=r"^out: s3://farm/other is not empty and holds no experiment"):
        ExperimentStorage("s3://farm/other").check_for("abc")
    with pytest.raises(ConfigError, match=r"^out: s3://farm/other/notes.txt exists and is not a folder"):
        ExperimentStorage("s3://farm/other/notes.txt").check_for("abc")


def test_a_trial_in_a_bucket_uploads_its_run_without_its_state_then_its_result(s3, tmp_path):
    storage = ExperimentStorage("s3://farm/trial")
    run = storage.run_dir("p0_s0")
    assert not str(run).startswith(str(tmp_path)) and run == ExperimentStorage("s3://farm/trial").run_dir("p0_s0")
    assert run != ExperimentStorage("s3://farm/other").run_dir("p0_s0")
    fake_run(run, [150])
    (run / "pretrain").mkdir()
    (run / "pretrain" / "iteration_0.pkl").write_text("x")
    assert not storage.finished("p0_s0")
    storage.finish("p0_s0", {"trial": "p0_s0", "x": 1.5}, run)
    assert storage.finished("p0_s0") and storage.read_result("p0_s0") == {"trial": "p0_s0", "x": 1.5}
    assert [k for k in bucket_keys(s3, prefix="trial/") if not k.endswith("/")] == [
        "trial/trials/p0_s0/result.json", "trial/trials/p0_s0/run/best/best_model.zip",
        "trial/trials/p0_s0/run/config.yaml", "trial/trials/p0_s0/run/evaluations.npz"]
    assert not run.parent.exists()
    manifest = {"name": "smoke", "digest": "abc", "trials": [], "fields": []}
    storage.write_manifest(manifest)  # before Ray, as run_experiment does
    with storage.staged() as stage:
        storage.stage_results(stage, ["p0_s0", "p1_s0"])
        assert files(stage) == {"experiment.json": json.dumps(manifest, indent=2) + "\n",
                                "trials/p0_s0/result.json": json.dumps({"trial": "p0_s0", "x": 1.5}, indent=2) + "\n",
                                "trials/p0_s0/run/best/best_model.zip": "best/best_model.zip",
                                "trials/p0_s0/run/config.yaml": "config.yaml",
                                "trials/p0_s0/run/evaluations.npz": "evaluations.npz"}
        (stage / "trials.csv").write_text("a\n1\n")
        storage.publish(stage, ["trials.csv", "claims.csv"])  # claims.csv not written: skipped
    assert s3.get_object(Bucket="farm", Key="trial/trials.csv")["Body"].read() == b"a\n1\n"
    assert storage.where("trials.csv") == "s3://farm/trial/trials.csv"


def test_a_uri_pyarrow_cannot_open_is_one_line():
    with pytest.raises(ConfigError, match=r"^out: nosuch://x/y: nosuch:// is not a storage an ") as e:
        ExperimentStorage("nosuch://x/y")
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match=r"^out: cannot open s3:///x: Missing bucket name") as e:
        ExperimentStorage("s3:///x")
    assert "\n" not in str(e.value)


def test_a_relative_local_folder_is_kept_by_its_absolute_path(tmp_path, monkeypatch):
    # the driver hands storage.uri to every trial, and Tune runs a trial in a working folder of its
    # own: a relative path there named another folder, where the trials' run folders went
    monkeypatch.chdir(tmp_path)
    storage = ExperimentStorage("results/exp")
    assert storage.uri == str(tmp_path / "results" / "exp")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert ExperimentStorage(storage.uri).run_dir("p0_s0") == tmp_path / "results" / "exp" / "trials" / "p0_s0" / "run"


def test_an_older_folders_pickled_names_load_inside_old_names_only():
    """Tune state of experiments written by 0.5 pickles farm.experiments._trial_dirname and
    farm.experiments_tune.Progress: they load to today's objects while run_experiment restores."""
    import pickle
    import sys

    from farm.studies.experiments.legacy import old_names
    from farm.studies.experiments.trial import trial_dirname
    from farm.studies.experiments.tune import Progress

    namer, callback = b"cfarm.experiments\n_trial_dirname\n.", b"cfarm.experiments_tune\nProgress\n."
    with pytest.raises(ModuleNotFoundError):
        pickle.loads(namer)
    with old_names():
        assert pickle.loads(namer) is trial_dirname and pickle.loads(callback) is Progress
    assert "farm.experiments" not in sys.modules and "farm.experiments_tune" not in sys.modules
    with pytest.raises(ModuleNotFoundError):
        pickle.loads(callback)


def test_a_run_folder_of_another_config_in_temporary_space_is_dropped_and_a_local_experiments_kept(s3, tmp_path):
    from farm.alloc.training.config import load_train_config
    from farm.alloc.training.runs import RunFolder
    from farm.studies.experiments.storage import drop_stale_run

    config = load_train_config(ROOT / "configs" / "train" / "tiny.yaml")
    other = config.model_copy(update={"seed": config.seed + 1})
    storage = ExperimentStorage("s3://farm/stale")
    run = RunFolder(storage.run_dir("p0_s0"))
    for trained, trial, dropped in ((config, config, False), (config, config.with_timesteps(7), False),
                                    (other, config, True)):
        shutil.rmtree(run.path, ignore_errors=True)
        fake_run(run.path, [150])
        run.write_config(trained)
        assert drop_stale_run(storage, run, trial) is dropped
        assert run.path.exists() is not dropped and (run.path / "checkpoints").exists() is not dropped
    fake_run(run.path, [150])
    (run.path / "config.yaml").write_text("{not yaml")  # unreadable: not this trial's either
    assert drop_stale_run(storage, run, config) and not run.path.exists()
    assert not drop_stale_run(storage, run, config)  # nothing there
    local = ExperimentStorage(tmp_path / "exp")
    mine = RunFolder(local.run_dir("p0_s0"))
    fake_run(mine.path, [150])
    mine.write_config(other)
    assert not drop_stale_run(local, mine, config) and mine.read_config().seed == other.seed
