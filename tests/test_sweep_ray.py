"""Sweeps on a real local Ray (2 CPUs): determinism whatever the number of
workers, resume, a worker killed by PID mid-sweep, the exported metrics, and one
seeding: game g of a case is the same game on every path that plays it."""

import os
import signal
import threading
import time
import urllib.request

import numpy as np
import pandas as pd
import pytest
from conftest import cmdline, descendants, write_sweep

from farm.games.sweep import SweepRun, load_sweep_config, run_sweep
from farm.runtime.metrics import EXPORTED

pytestmark = pytest.mark.ray

@pytest.fixture
def config(tmp_path):
    return load_sweep_config(write_sweep(tmp_path / "sweep.yaml"))


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
        assert info["workers"] == workers and info["done"] == 16
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


@pytest.mark.slow
def test_worker_killed_mid_sweep_every_shard_exactly_once(ray_local, tmp_path, reference):
    # Bigger shards (about a second each) so that a worker is caught mid-shard; 2 points, 2
    # shards each: the 2 workers are busy until the last shard.
    config = load_sweep_config(write_sweep(tmp_path / "kill.yaml", games_per_point=2400, shard_games=1200,
                                           base={"n_evaders": 2, "t_max": 40, "evader_policy": "centroid"},
                                           vary={"grid": {"n_pursuers": [2, 4]}}))
    out = tmp_path / "out"
    result = {}
    thread = threading.Thread(target=lambda: result.update(info=run_sweep(config, out, show_progress=False)[1]))
    thread.start()
    killed = None
    deadline = time.time() + 120
    while killed is None and time.time() < deadline and thread.is_alive():
        for pid in descendants():  # the shared Ray's workers, never another xdist worker's
            if cmdline(pid).startswith(b"ray::_remote_shard"):
                time.sleep(0.3)  # let it get into the shard
                os.kill(pid, signal.SIGKILL)
                killed = pid
                break
        time.sleep(0.05)
    thread.join(timeout=600)
    assert killed is not None, "no shard-running worker was found to kill"
    info = result["info"]
    assert info["done"] == len(SweepRun(config, out).all_shards())  # the killed worker's shard: retried by Ray
    files = sorted(p.name for p in (out / "shards").iterdir())
    assert files == sorted(s.file_name for s in SweepRun(config, out).all_shards())

    # Every metric the dashboard queries is exported through Ray's Prometheus endpoint (scraped
    # at once: Ray drops a gauge's series when the process that set it exits or lets it go).
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

    got = read_games(config, out)
    assert not got.duplicated(["point", "game"]).any() and len(got) == 2 * 2400
    pd.testing.assert_frame_equal(got, reference(config))


@pytest.mark.slow
def test_one_seeding_every_path_plays_the_same_games(ray_local, tmp_path):
    """Games 0..7 of one case with seed 5, through run_case, a 1-worker and a 2-worker sweep,
    the capture-time service and `farm eval --fidelity games`' client (its games as Ray tasks and
    in process): the same capture and escape times, bit for bit."""
    import ray

    from farm.alloc.evaluation.fidelity import FreshGames
    from farm.games.tasks import _remote_shard
    from farm.service import CaptureTimeClient, GameSettings, get_service
    from workers import CaptureStats, run_case, run_games

    settings = GameSettings.of(games=8, seed=5, t_max=20.0, tau=8.0, pursuer_policy="pure_pursuit",
                                  evader_policy="target", exit_point=(0.0, 5.0), pursuer_speed=0.8)
    case = settings.key(2, 3).case
    games = run_games(case, 5, 0, 8)
    assert np.isfinite(games.capture_times).any() and np.isfinite(games.escape_times).any()
    per_game, stats = run_case(case, 8, seed=5, batch_size=3)

    path = tmp_path / "sweep.yaml"
    path.write_text("name: seeding\nseed: 5\ngames_per_point: 8\nshard_games: 3\n"
                    "base: {n_pursuers: 2, n_evaders: 3, t_max: 20, tau: 8, pursuer_policy: pure_pursuit, "
                    "evader_policy: target, exit_point: [0, 5], pursuer_speed: 0.8}\n")
    config = load_sweep_config(path)
    assert config.points()[0].case == case
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        run_sweep(config, out, workers=workers, show_progress=False)
        rows = read_games(config, out)
        np.testing.assert_array_equal(np.stack(rows["capture_times"]), games.capture_times)
        np.testing.assert_array_equal(np.stack(rows["escape_times"]), games.escape_times)
        pd.testing.assert_frame_equal(rows[per_game.columns].reset_index(drop=True), per_game)

    service = get_service(tmp_path / "s.sqlite", name="svc-seeding")
    key = settings.key(2, 3)
    shard_rows = pd.concat([df for df, _ in ray.get([_remote_shard.remote(key.case, key.seed, 0, 5),
                                                      _remote_shard.remote(key.case, key.seed, 5, 8)])],
                           ignore_index=True)
    pd.testing.assert_frame_equal(shard_rows, per_game)  # the service's shard tasks play the same games
    value = CaptureTimeClient(settings, service=service).get(2, 3)
    np.testing.assert_equal(value.flat(), stats.flat())

    for in_process in (False, True):  # as Ray tasks, and in this process (a run of service.mode local)
        games_backend = FreshGames(CaptureTimeClient(settings, service=service), first_game=0, in_process=in_process)
        fidelity = CaptureTimeClient(settings, backend=games_backend)
        for _ in range(8):
            fidelity.get_many([(2, 3)])
        assert [d["game"] for d in games_backend.differences] == list(range(8))
        np.testing.assert_array_equal(np.array([d["capture_times"] for d in games_backend.differences]),
                                      games.capture_times)
        assert isinstance(fidelity.get_many([(2, 3)])[0], CaptureStats) and games_backend.differences[-1]["game"] == 8
