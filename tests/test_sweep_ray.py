"""Sweeps on a real local Ray (2 CPUs): determinism whatever the number of
workers, resume, a worker killed by PID mid-sweep, and the exported metrics."""

import os
import signal
import textwrap
import threading
import time
import urllib.request

import pandas as pd
import psutil
import pytest

from farm.config import load_sweep_config
from farm.metrics import EXPORTED
from farm.sweep import SweepRun, run_sweep

SWEEP = """
name: ray-test
seed: 7
games_per_point: 24
shard_games: 6
base: {n_evaders: 2, t_max: 20}
vary:
  grid: {n_pursuers: [2, 4], evader_policy: [centroid, constant_area]}
"""


@pytest.fixture
def config(tmp_path):
    path = tmp_path / "sweep.yaml"
    path.write_text(textwrap.dedent(SWEEP))
    return load_sweep_config(path)


def read_games(config, out):
    run = SweepRun(config, out)
    return run.read_games()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The same sweep run in-process, without Ray."""
    def make(config):
        out = tmp_path_factory.mktemp("in-process")
        run_sweep(config, out, use_ray=False, show_progress=False)
        return read_games(config, out)
    return make


def test_same_numbers_on_one_and_two_workers(ray_local, config, tmp_path, reference):
    expected = reference(config)
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        summary, info = run_sweep(config, out, workers=workers, show_progress=False)
        assert info["workers"] == workers and info["done"] == 16 and info["failed"] == 0
        pd.testing.assert_frame_equal(read_games(config, out), expected)
    a = pd.read_parquet(tmp_path / "w1" / "summary.parquet")
    b = pd.read_parquet(tmp_path / "w2" / "summary.parquet")
    pd.testing.assert_frame_equal(a, b)
    assert len(a) == 4 and (a["n_games"] == 24).all()


def test_resume_runs_only_missing_shards(ray_local, config, tmp_path, reference):
    out = tmp_path / "resume"
    run_sweep(config, out, show_progress=False)
    shards = sorted((out / "shards").iterdir())
    for p in shards[::3]:
        p.unlink()
    (out / "shards" / ".p00000-s00000.parquet.123.tmp").write_bytes(b"partial write")
    kept = {p.name: p.stat().st_mtime_ns for p in shards[1::3]}
    _, info = run_sweep(config, out, show_progress=False)
    assert info["skipped"] == len(shards) - len(shards[::3]) and info["done"] == len(shards[::3])
    assert {p.name: p.stat().st_mtime_ns for p in shards[1::3]} == kept
    assert not list((out / "shards").glob(".*.tmp"))
    pd.testing.assert_frame_equal(read_games(config, out), reference(config))
    _, info = run_sweep(config, out, show_progress=False)
    assert info["done"] == 0 and info["skipped"] == len(shards)


def scrape(port) -> str:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as r:
        return r.read().decode()


def test_worker_killed_mid_sweep_every_shard_exactly_once(ray_local, tmp_path, reference):
    path = tmp_path / "kill.yaml"
    # Bigger shards (about a second each) so that a worker is caught mid-shard.
    path.write_text(textwrap.dedent(SWEEP).replace("games_per_point: 24\nshard_games: 6", "games_per_point: 2400\nshard_games: 1200")
                    .replace("t_max: 20", "t_max: 40"))
    config = load_sweep_config(path)
    out = tmp_path / "out"
    result = {}
    thread = threading.Thread(target=lambda: result.update(info=run_sweep(config, out, show_progress=False)[1]))
    thread.start()
    killed = None
    deadline = time.time() + 120
    while killed is None and time.time() < deadline and thread.is_alive():
        for proc in psutil.process_iter(["pid", "cmdline"]):
            if "_remote_shard" in " ".join(proc.info["cmdline"] or []):
                time.sleep(0.3)  # let it get into the shard
                os.kill(proc.info["pid"], signal.SIGKILL)
                killed = proc.info["pid"]
                break
        time.sleep(0.05)
    thread.join(timeout=600)
    assert killed is not None, "no shard-running worker was found to kill"
    info = result["info"]
    assert info["failed"] >= 1 and info["retried"] == info["failed"]
    files = sorted(p.name for p in (out / "shards").iterdir())
    assert files == sorted(s.file_name for s in SweepRun(config, out).all_shards())
    got = read_games(config, out)
    assert not got.duplicated(["point", "game"]).any() and len(got) == 4 * 2400
    pd.testing.assert_frame_equal(got, reference(config))

    # Every metric the dashboard queries is exported through Ray's Prometheus endpoint.
    from test_dashboards import dashboard_metric_names

    wanted = {m for m in set(EXPORTED) | dashboard_metric_names() if '_service_' not in m}
    deadline = time.time() + 60
    while time.time() < deadline:
        text = scrape(ray_local)
        missing = {m for m in wanted if f"\n{m}{{" not in text and f"\n{m} " not in text}
        if not missing:
            break
        time.sleep(1)
    assert not missing, f"not exported: {sorted(missing)}"
    assert 'sweep="ray-test"' in text
