"""MLflow tracking of `farm train` (farm.alloc.training.tracking) on a real SQLite tracking
store, read back with MLflow's own client: the run's params, its evaluation curve, its final
metrics and artifacts are the run folder's (metrics.json, evaluations.npz, model.zip); a resume
goes on logging into the same MLflow run; tracking changes no number; a store MLflow cannot
open is one line before anything is written. `farm experiments`' MLflow runs (one per trial,
through farm.studies.experiments.tracking.TrialRuns) are checked in tests/test_experiments.py,
on its tracked smoke grid and its tracked driver-killed run; here, what TrialRuns logs of a
report."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from farm.core.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def tiny(tmp: Path, n_timesteps: int = 300, uri: str | None = None, name: str = "tiny.yaml") -> Path:
    """configs/train/tiny.yaml, its store in tmp, its length n_timesteps, tracked at uri."""
    raw = yaml.safe_load((REPO / "configs/train/tiny.yaml").read_text())
    raw["service"]["store"] = str(tmp / "store.sqlite")
    raw["td3"]["n_timesteps"] = n_timesteps
    if uri is not None:
        raw["tracking"] = {"mlflow": {"tracking_uri": uri}}
    path = tmp / name
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def trained(path: Path, run: Path, resume: bool = False) -> dict:
    from farm.alloc.training import load_train_config, train

    return train(load_train_config(path), run, resume=resume, show_progress=False)


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """A tiny run trained 300 steps with MLflow tracking on an SQLite store, resumed to 450;
    and the same 300 steps untracked. (tmp, run folder, metrics at 300, at 450, untracked folder)."""
    tmp = tmp_path_factory.mktemp("tracked")
    uri = str(tmp / "mlflow.db")  # a plain path ending in .db: an SQLite store
    run = tmp / "run"
    first = trained(tiny(tmp, 300, uri), run)
    first_evaluations = dict(np.load(run / "evaluations.npz"))
    second = trained(tiny(tmp, 450, uri, "tiny450.yaml"), run, resume=True)
    plain = tmp / "plain"
    trained(tiny(tmp, 300, None, "plain.yaml"), plain)
    return tmp, run, first, second, plain, first_evaluations


def client_of(tmp: Path):
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=f"sqlite:///{tmp / 'mlflow.db'}")


@pytest.mark.slow
def test_a_tracked_run_logs_its_params_curve_metrics_and_files(tracked):
    tmp, run, _, second, _, _ = tracked
    client = client_of(tmp)
    saved = json.loads((run / "mlflow_run.json").read_text())
    experiment = client.get_experiment_by_name("tiny")  # the config's name
    assert experiment is not None and saved["experiment_id"] == experiment.experiment_id
    runs = client.search_runs([experiment.experiment_id])
    assert [r.info.run_id for r in runs] == [saved["run_id"]]  # the resume went on in the same run
    logged = runs[0]
    assert logged.info.status == "FINISHED" and logged.info.run_name == "tiny"
    params = logged.data.params
    assert params["algo"] == "td3" and params["env.grid_size"] == "3" and params["td3.batch_size"] == "64"
    assert not any(k.startswith("tracking") for k in params)  # tracking is no part of the run

    history = client.get_metric_history(saved["run_id"], "eval/mean_return")
    evaluations = np.load(run / "evaluations.npz")
    assert sorted(m.step for m in history) == evaluations["timesteps"].tolist() == [150, 300, 450]
    by_step = {m.step: m.value for m in history}
    for step, results in zip(evaluations["timesteps"], evaluations["results"]):
        assert by_step[int(step)] == pytest.approx(float(np.mean(results)), rel=1e-12)

    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics == second
    for key, value in metrics.items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            assert logged.data.metrics[key] == pytest.approx(value, rel=1e-12), key
    assert logged.data.metrics["timesteps"] == 450
    artifacts = {a.path for a in client.list_artifacts(saved["run_id"])}
    assert {"model.zip", "metrics.json", "config.yaml", "evaluations.csv", "training_curve.png"} <= artifacts
    # an SQLite store keeps its artifacts beside the database, not in the working folder
    assert (tmp / "mlartifacts").is_dir() and not (Path.cwd() / "mlruns").exists()


@pytest.mark.slow
def test_tracking_changes_no_number(tracked):
    _, _, first, _, plain, first_evaluations = tracked
    untracked = json.loads((plain / "metrics.json").read_text())
    timing = {"wall_seconds", "steps_per_second", "update_seconds", "outside_update_share"}
    assert ({k: v for k, v in first.items() if k not in timing}
            == {k: v for k, v in untracked.items() if k not in timing})
    plain_evaluations = np.load(plain / "evaluations.npz")
    for key in ("timesteps", "results", "ep_lengths"):
        np.testing.assert_array_equal(first_evaluations[key], plain_evaluations[key])


def test_a_store_mlflow_cannot_open_is_one_line_and_writes_nothing(tmp_path):
    run = tmp_path / "run"
    with pytest.raises(ConfigError) as e:
        trained(tiny(tmp_path, 300, "/proc/no-such-folder/mlflow.db"), run)
    message = str(e.value)
    assert "\n" not in message and message.startswith("tracking.mlflow.tracking_uri: MLflow cannot use")
    assert not run.exists()


@pytest.mark.parametrize("raw, problem", [
    ({"mlflow": {"tracking_uri": ""}}, "tracking.mlflow.tracking_uri"),
    ({"mlflow": {"tracking_uri": "x.db", "colour": 1}}, "tracking.mlflow.colour"),
    ({"mlflow": {}}, "tracking.mlflow.tracking_uri"),
    ({"wandb": {}}, "tracking.wandb"),
])
def test_a_bad_tracking_block_is_one_line(tmp_path, raw, problem):
    from farm.alloc.training import load_train_config

    path = tiny(tmp_path)
    doc = yaml.safe_load(path.read_text())
    doc["tracking"] = raw
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError) as e:
        load_train_config(path)
    assert "\n" not in str(e.value) and problem in str(e.value)


def test_a_local_path_becomes_a_store_uri_and_params_are_flat(tmp_path):
    from farm.core.tracking import MlflowParams, flat_params

    assert MlflowParams(tracking_uri=str(tmp_path / "m.db")).tracking_uri == f"sqlite:///{tmp_path / 'm.db'}"
    assert MlflowParams(tracking_uri=str(tmp_path / "store")).tracking_uri == (tmp_path / "store").as_uri()
    assert MlflowParams(tracking_uri="http://127.0.0.1:5000").tracking_uri == "http://127.0.0.1:5000"
    flat = flat_params({"env": {"grid_size": 3, "seed": None}, "net": [400, 300], "algo": "td3", "long": "x" * 7000})
    assert flat["env.grid_size"] == "3" and flat["env.seed"] == "null" and flat["net"] == "[400, 300]"
    assert flat["algo"] == "td3" and len(flat["long"]) == 6000


def test_a_tune_report_s_numbers_are_its_metrics_flattened_without_its_config():
    from farm.core.tracking import flattened
    from farm.studies.experiments.tracking import report_metrics

    nested = {"a": {"b": 1, "c": {"d": "x"}}, "e": {}, "f": [1]}
    assert flattened(nested, "/") == {"a/b": 1, "a/c/d": "x", "e": {}, "f": [1]}
    assert flattened(nested) == {"a.b": 1, "a.c.d": "x", "e": {}, "f": [1]}
    report = {"timesteps_total": 300, "done": True, "eval": {"return": np.float32(1.5), "note": "best"},
              "phase": "done", "config": {"spec": {"seed": 0}}, "missing": None, "curve": [1.0, 2.0],
              "ratio": float("nan"), "count": np.int64(7), "flag": np.bool_(False)}
    metrics = report_metrics(report)
    assert set(metrics) == {"timesteps_total", "done", "eval/return", "ratio", "count", "flag"}
    assert metrics["timesteps_total"] == 300.0 and metrics["done"] == 1.0 and metrics["eval/return"] == 1.5
    assert np.isnan(metrics["ratio"]) and metrics["count"] == 7.0 and metrics["flag"] == 0.0
    assert all(type(v) is float for v in metrics.values())


def test_a_trial_started_again_after_a_restore_reopens_its_run_and_a_new_experiment_opens_its_own(tmp_path):
    """The order CI met (stop 44): Tune ended p0_s0 (its run FINISHED), the driver was killed before
    Tune saved that, and the restored experiment (its callbacks unpickled from Tune's state)
    started p0_s0 again. That reopens p0_s0's run; it does not open a second. An experiment made
    again in the same storage (a new TrialRuns: a new instance) opens runs of its own."""
    import pickle

    from mlflow.tracking import MlflowClient
    from ray.tune.experiment import Trial

    from farm.core.tracking import MlflowParams, mlflow_client, mlflow_experiment
    from farm.studies.experiments.tracking import TrialRuns

    params = MlflowParams(tracking_uri=str(tmp_path / "mlflow.db"))
    mlflow_experiment(mlflow_client(params), params, "smoke")

    def trial(name: str) -> Trial:
        made = Trial("run_trial", config={"spec": {"seed": int(name[-1])}}, stub=True)
        made.custom_trial_name = name
        return made

    storage = str(tmp_path / "exp")
    first = TrialRuns(params, "smoke", storage, tags={"farm.kind": "experiment"})
    done, going = trial("p0_s0"), trial("p0_s1")
    for t in (done, going):
        first.log_trial_start(t)
        first.log_trial_result(1, t, {"timesteps_total": 150})
    first.log_trial_result(2, done, {"timesteps_total": 300})
    first.log_trial_end(done)

    restored = pickle.loads(pickle.dumps(first))  # as Tune's restore has it: no client, no run map
    for t in (done, going):
        restored.log_trial_start(t)
        restored.log_trial_result(2, t, {"timesteps_total": 300})
        restored.log_trial_end(t)

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    experiment_id = client.get_experiment_by_name("smoke").experiment_id
    runs = client.search_runs([experiment_id])
    assert sorted(r.info.run_name for r in runs) == ["p0_s0", "p0_s1"]
    assert all(r.info.status == "FINISHED" for r in runs)
    for r in runs:
        steps = sorted(m.step for m in client.get_metric_history(r.info.run_id, "timesteps_total"))
        assert steps == {"p0_s0": [150, 300, 300], "p0_s1": [150, 300]}[r.info.run_name]
        assert r.data.params["spec/seed"] == r.info.run_name[-1]

    again = TrialRuns(params, "smoke", storage, tags={"farm.kind": "experiment"})  # the folder deleted, made again
    again.log_trial_start(trial("p0_s0"))
    again.log_trial_end(trial("p0_s0"))
    assert sorted(r.info.run_name for r in client.search_runs([experiment_id])) == ["p0_s0", "p0_s0", "p0_s1"]
