"""Tracking that fails or cannot work (farm.core.tracking, farm.alloc.training.tracking,
farm.studies.experiments.tracking), on a real SQLite MLflow store and real sockets: a tracking
store damaged while a run trains is one warning, and the run finishes with the model and metrics
of an untracked run; Tune's MLflow logger failing stops nothing; a tracking URI that cannot work
(a damaged or read-only store, a database server without its driver, a server where nothing
answers, no host, the capture-time store's own file) is one line before any work, within
seconds."""

import json
import socket
import time
import warnings
import zipfile
from pathlib import Path

import pytest
import yaml
from conftest import free_port, immutable
from helpers import farm_refusal
from stable_baselines3.common.callbacks import BaseCallback

from farm.core.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
SECONDS = 10  # a URI that cannot work is refused within this


def tiny(tmp: Path, uri: str | None, name: str = "tiny.yaml", store: Path | None = None) -> Path:
    """configs/train/tiny.yaml (300 steps, evaluated at 150 and 300), its store in tmp (or store),
    tracked at uri."""
    raw = yaml.safe_load((REPO / "configs/train/tiny.yaml").read_text())
    raw["service"]["store"] = str(store or tmp / "store.sqlite")
    if uri is not None:
        raw["tracking"] = {"mlflow": {"tracking_uri": uri}}
    path = tmp / name
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def trained(path: Path, run: Path, callbacks=()) -> dict:
    from farm.alloc.training import load_train_config, train

    return train(load_train_config(path), run, show_progress=False, callbacks=list(callbacks))


class Damage(BaseCallback):
    """At step `at`, overwrite the first bytes of the file at path with garbage, in place (the
    store's open connection sees it): a tracking store damaged while the run trains."""

    def __init__(self, path: Path, at: int):
        super().__init__()
        self.path, self.at, self.done = path, at, False

    def _on_step(self) -> bool:
        if not self.done and self.num_timesteps >= self.at:
            with open(self.path, "r+b") as f:
                f.write(b"this is no longer an SQLite database" * 200)
            self.done = True
        return True


def model_members(path: Path) -> dict:
    """model.zip's members but SB3's data (it holds the wall-clock start time), by name."""
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in z.namelist() if n != "data"}


TIMING = {"wall_seconds", "steps_per_second", "update_seconds", "outside_update_share"}


@pytest.mark.slow
def test_a_store_damaged_mid_run_is_one_warning_and_the_run_finishes_as_an_untracked_one(tmp_path):
    db = tmp_path / "tracking" / "mlflow.db"
    tracked, plain = tmp_path / "tracked", tmp_path / "plain"
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        metrics = trained(tiny(tmp_path, str(db)), tracked, [Damage(db, 100)])
    said = [str(w.message) for w in seen if "tracking.mlflow" in str(w.message)]
    assert len(said) == 1 and "\n" not in said[0], said
    assert said[0].startswith("tracking.mlflow: MLflow failed logging the evaluation of step 150 (")
    assert said[0].endswith("the run goes on untracked")
    untracked = trained(tiny(tmp_path, None, "plain.yaml"), plain)
    assert (tracked / "model.zip").is_file() and (tracked / "metrics.json").is_file()
    written = json.loads((tracked / "metrics.json").read_text())
    assert written == metrics
    assert {k: v for k, v in metrics.items() if k not in TIMING} == {k: v for k, v in untracked.items()
                                                                     if k not in TIMING}
    assert model_members(tracked / "model.zip") == model_members(plain / "model.zip")


def _open_mlflow_runs(tmp_path):
    from farm.core.tracking import MlflowParams
    from farm.studies.experiments.tracking import TrialRuns

    db = tmp_path / "mlflow.db"
    params = MlflowParams(tracking_uri=str(db))
    return db, TrialRuns(params, "smoke", str(tmp_path / "exp"), tags={"farm.kind": "experiment"})


def _trial(name: str):
    from ray.tune.experiment import Trial

    made = Trial("run_trial", config={"spec": {"seed": 0}}, stub=True)
    made.custom_trial_name = name
    return made


def test_tune_s_mlflow_logger_failing_stops_nothing(tmp_path):
    """Tune stops an experiment whose callback raises: TrialRuns, its store damaged after a
    trial's first report, says so once and goes on (every later call skipped)."""
    db, runs = _open_mlflow_runs(tmp_path)
    first, second = _trial("p0_s0"), _trial("p0_s1")
    runs.log_trial_start(first)
    runs.log_trial_result(1, first, {"timesteps_total": 150})
    with open(db, "r+b") as f:
        f.write(b"garbage" * 1000)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        runs.log_trial_result(2, first, {"timesteps_total": 300})
        runs.log_trial_end(first)
        runs.log_trial_start(second)
        runs.log_trial_result(1, second, {"timesteps_total": 150})
        runs.log_trial_end(second, failed=True)
    said = [str(w.message) for w in seen]
    assert len(said) == 1 and "\n" not in said[0], said
    assert said[0].startswith("tracking.mlflow: MLflow failed logging trial p0_s0's report (")
    assert said[0].endswith("the experiment goes on untracked")


def test_tune_s_mlflow_logger_on_a_store_gone_read_only_stops_nothing(tmp_path):
    db, runs = _open_mlflow_runs(tmp_path)
    first = _trial("p0_s0")
    runs.log_trial_start(first)
    with immutable(tmp_path), warnings.catch_warnings(record=True) as seen:  # SQLite's journal cannot be made
        warnings.simplefilter("always")
        runs.log_trial_result(1, first, {"timesteps_total": 150})
        runs.log_trial_end(first)
    said = [str(w.message) for w in seen]
    assert len(said) == 1 and said[0].startswith("tracking.mlflow: MLflow failed logging trial p0_s0's report")



def refused_train(tmp_path: Path, uri: str, store: Path | None = None, seconds: float = SECONDS) -> str:
    """`farm train` of tiny tracked at uri: its one-line error (exit status 2), within seconds,
    nothing written to the run folder."""
    from conftest import farm_main

    run = tmp_path / "run"
    t0 = time.perf_counter()
    status, _, err = farm_main("train", tiny(tmp_path, uri, store=store), "--out", run, "--quiet")
    took = time.perf_counter() - t0
    line = farm_refusal(status, err)
    assert took < seconds, (took, line)
    assert not run.exists()
    return line


def test_a_damaged_tracking_store_is_one_line(tmp_path):
    db = tmp_path / "mlflow.db"
    db.write_bytes(b"not a database" * 100)
    line = refused_train(tmp_path, str(db))
    assert line == f"farm: error: tracking.mlflow.tracking_uri: sqlite:///{db} is not a sound SQLite file " \
                   f"(file is not a database)"


def test_a_store_a_killed_writer_left_mid_transaction_is_rolled_back_not_refused(tmp_path):
    """A writer killed mid-transaction leaves a hot journal; the check rolls it back (as MLflow's
    next connection would) instead of calling the store unsound."""
    import os
    import signal
    import sqlite3
    import subprocess
    import sys

    from farm.core.tracking import MlflowParams, check_tracking_uri

    db = tmp_path / "mlflow.db"
    with sqlite3.connect(db) as con:
        con.executescript("CREATE TABLE experiments (id INTEGER); CREATE TABLE runs (id INTEGER, body TEXT);"
                          "INSERT INTO runs VALUES (0, 'kept');")
    con.close()
    writer = ("import os, signal, sqlite3, sys\n"
              "db = sqlite3.connect(sys.argv[1]); db.execute('PRAGMA cache_size=1'); db.execute('BEGIN')\n"
              "for i in range(2000): db.execute('INSERT INTO runs VALUES (?, ?)', (i, 'x' * 2000))\n"
              "os.kill(os.getpid(), signal.SIGKILL)\n")
    done = subprocess.run([sys.executable, "-c", writer, str(db)], capture_output=True)
    assert done.returncode == -signal.SIGKILL
    assert (tmp_path / "mlflow.db-journal").stat().st_size > 0  # the killed transaction's pages
    check_tracking_uri(MlflowParams(tracking_uri=str(db)))
    assert not os.path.exists(tmp_path / "mlflow.db-journal")
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT id, body FROM runs").fetchall() == [(0, "kept")]
    con.close()


def test_a_tracking_store_in_a_read_only_folder_is_one_line(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    with immutable(folder):
        line = refused_train(tmp_path, str(folder / "mlflow.db"))
        assert list(folder.iterdir()) == []
    assert line == (f"farm: error: tracking.mlflow.tracking_uri: sqlite:///{folder / 'mlflow.db'} is read-only "
                    f"(its folder {folder} is not writable); make it writable or name another")


@pytest.mark.parametrize("uri, module", [("postgresql://farm:secret@127.0.0.1/runs", "psycopg"),
                                         ("mysql://farm@127.0.0.1/runs", "MySQLdb")])
def test_a_database_server_without_its_driver_is_one_line(tmp_path, uri, module):
    import importlib.util

    if importlib.util.find_spec(module) is not None:
        pytest.skip(f"{module} is installed here")
    line = refused_train(tmp_path, uri)
    assert line.startswith(f"farm: error: tracking.mlflow.tracking_uri: {uri.replace(':secret@', ':***@')} "
                           f"cannot be used: its database driver (the Python module ")
    assert "secret" not in line


def test_a_tracking_server_where_nothing_answers_is_refused_at_once(tmp_path):
    port = free_port()
    line = refused_train(tmp_path, f"http://127.0.0.1:{port}")
    assert line.startswith(f"farm: error: tracking.mlflow.tracking_uri: http://127.0.0.1:{port} does not answer: "
                           f"nothing at 127.0.0.1:{port} within 5 s (")


@pytest.mark.slow
def test_a_tracking_server_that_never_replies_is_refused_within_seconds(tmp_path):
    """It accepts connections and says nothing: MLflow's own wait, bounded while the URI is
    checked (its default retries for minutes); the bound here leaves time to import MLflow."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(16)
        port = listener.getsockname()[1]
        line = refused_train(tmp_path, f"http://127.0.0.1:{port}", seconds=2 * SECONDS)
    assert line.startswith(f"farm: error: tracking.mlflow.tracking_uri: MLflow cannot use 'http://127.0.0.1:{port}'")


@pytest.mark.slow
def test_a_tracking_server_that_never_replies_is_refused_within_seconds_by_the_api(tmp_path):
    """The same through the API: the check's wait is MLflow's timeout, once (CHECK_HTTP), and
    MLflow's settings are as they were after it."""
    import os

    from farm.core.tracking import MlflowParams, open_experiment

    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(16)
        port = listener.getsockname()[1]
        before = {k: os.environ.get(k) for k in ("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "MLFLOW_HTTP_REQUEST_TIMEOUT")}
        t0 = time.perf_counter()
        with pytest.raises(ConfigError) as e:
            open_experiment(MlflowParams(tracking_uri=f"http://127.0.0.1:{port}"), "x")
        assert time.perf_counter() - t0 < SECONDS
    assert "\n" not in str(e.value) and "timed out" in str(e.value)
    assert {k: os.environ.get(k) for k in before} == before


@pytest.mark.parametrize("uri", ["http://", "https:///x"])
def test_a_tracking_server_without_a_host_is_one_line(tmp_path, uri):
    line = refused_train(tmp_path, uri)
    assert line.endswith(f"tracking.mlflow.tracking_uri: {uri} names no host; give {uri.split(':')[0]}://HOST:PORT")


def test_the_capture_time_store_is_never_a_tracking_store(tmp_path):
    """Named as the tracking URI, the run's capture-time store would get MLflow's tables."""
    import sqlite3

    from farm.service.store import StatsStore

    store = tmp_path / "store.sqlite"
    StatsStore(store).close()
    before = store.read_bytes()
    line = refused_train(tmp_path, str(store), store=store)
    assert line == (f"farm: error: tracking.mlflow.tracking_uri: sqlite:///{store} is the capture-time store's "
                    f"file; keep MLflow's runs in a file of their own (say mlflow.db beside it)")
    other = tmp_path / "other.sqlite"  # another run's store, named as this run's tracking store
    StatsStore(other).close()
    line = refused_train(tmp_path, str(other), store=store)
    assert line == (f"farm: error: tracking.mlflow.tracking_uri: sqlite:///{other} holds tables that are not "
                    f"MLflow's (stats); name a file of its own")
    assert store.read_bytes() == before
    tables = {r[0] for r in sqlite3.connect(other).execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert tables == {"stats"}


def test_an_experiment_refuses_the_same_before_ray(tmp_path):
    """farm experiments: the capture-time store named as the tracking store, and a tracking
    server where nothing answers, in one line before Ray (conftest: a Ray would be a closed port)."""
    from conftest import farm_main

    raw = yaml.safe_load((REPO / "configs/experiments/smoke.yaml").read_text())
    store = tmp_path / "store.sqlite"
    for uri, expected in [(str(store), "is the capture-time store's file"),
                          (f"http://127.0.0.1:{free_port()}", "does not answer")]:
        raw.update(base=str(REPO / raw["base"]), store=str(store), tracking={"mlflow": {"tracking_uri": uri}})
        path = tmp_path / "smoke.yaml"
        path.write_text(yaml.safe_dump(raw, sort_keys=False))
        t0 = time.perf_counter()
        status, _, err = farm_main("experiments", path, "--out", tmp_path / "exp", "--quiet")
        assert time.perf_counter() - t0 < SECONDS
        assert status == 2 and len(err.strip().splitlines()) == 1, err
        assert err.startswith("farm: error: tracking.mlflow.tracking_uri: ") and expected in err, err
        assert not store.exists() and not (tmp_path / "exp").exists()


def test_a_failing_tracker_call_is_one_warning_with_the_trackers_loggers_quiet_and_the_run_ended_failed():
    """What MLflow's own loggers say about a failure (a 40-line ERROR block) is not printed: the
    project's one warning says it; the MLflow run is ended FAILED, once, where the store takes it."""
    import logging

    from farm.core.tracking import Guard, TrackingWarning

    records, ended = [], []
    handler = logging.Handler()
    handler.emit = records.append
    root = logging.getLogger("mlflow")
    root.addHandler(handler)
    level = root.level

    def failing():
        logging.getLogger("mlflow.store.db.utils").error("a block of forty lines")
        logging.getLogger("sqlalchemy.engine").error("and a chained traceback")
        raise RuntimeError("database disk image is malformed")

    guard = Guard("the run", on_off=lambda: ended.append("FAILED"))
    try:
        with pytest.warns(TrackingWarning) as warned:
            assert guard("logging the metrics", failing) is None
            assert guard("logging the metrics", failing) is None  # off: skipped, not said again
    finally:
        root.removeHandler(handler)
    assert [str(w.message) for w in warned] == [
        "tracking.mlflow: MLflow failed logging the metrics (database disk image is malformed); "
        "the run goes on untracked"]
    assert records == [] and ended == ["FAILED"] and root.level == level
