"""The farm as a user runs it: `farm sweep` subprocesses on real Ray clusters
started with `ray start` on loopback, a driver killed by SIGKILL, a second node
lost mid-sweep, `ray job submit` of a sweep and of an experiment, and a head on this
machine joined by every address form (`farm exploit` and `farm robust` among them)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import cmdline, free_port, ray_start_lock, session, signal_all, write_sweep

from farm.games.sweep import SweepRun, load_sweep_config, run_sweep

pytestmark = [pytest.mark.ray, pytest.mark.own_ray, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
ENV = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "RAY_AUTH_MODE": "disabled",
       "PYTHONUNBUFFERED": "1"}
ENV.pop("RAY_ADDRESS", None)
ENV.pop("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", None)  # real multi-node clusters: Ray's own binding (conftest)

@pytest.fixture(scope="module")
def config_path(tmp_path_factory):
    return write_sweep(tmp_path_factory.mktemp("sweep") / "sweep.yaml", name="cluster-test", seed=3,
                       games_per_point=64, shard_games=8, base={"n_evaders": 2, "t_max": 30},
                       vary={"grid": {"n_pursuers": [3, 5], "evader_policy": ["centroid", "constant_area"]}})


@pytest.fixture(scope="module")
def in_process_games(config_path, tmp_path_factory):
    """The sweep's games played uninterrupted in process, once for the tests that compare with them."""
    config = load_sweep_config(config_path)
    out = tmp_path_factory.mktemp("in-process")
    run_sweep(config, out, use_ray=False, show_progress=False)
    return SweepRun(config, out).read_games()


def wait_for_shards(out: Path, n: int, proc, timeout=180):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if (out / "shards").exists() and len(list((out / "shards").glob("*.parquet"))) >= n:
            return
        if proc.poll() is not None:
            said = proc.stdout.read() if proc.stdout is not None else ""
            raise AssertionError(f"the sweep ended early: {proc.returncode}\n{said[-3000:]}")
        time.sleep(0.1)
    raise AssertionError("shards did not appear in time")


class Groups:
    """Process groups started here, killed at the end (Ray daemons included)."""

    def __init__(self):
        self.pgids = []
        self.temp_dirs = []

    def popen(self, args, **kw):
        proc = subprocess.Popen(args, env=ENV, start_new_session=True, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, **kw)
        self.pgids.append(proc.pid)
        return proc

    def kill(self, pgid):
        try:
            os.killpg(pgid, signal.SIGKILL)
        except ProcessLookupError:
            pass

    def close(self):
        for pgid in self.pgids:
            self.kill(pgid)
        for d in self.temp_dirs:
            shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def groups():
    g = Groups()
    yield g
    g.close()


def ray_start(groups, *args):
    """`ray start <args>` on loopback (ray_start_lock held); returns its pid, the id of the
    session its daemons and their workers run in."""
    with ray_start_lock():
        proc = groups.popen([str(BIN / "ray"), "start", "--node-ip-address=127.0.0.1", *args])
        out, _ = proc.communicate(timeout=180)
    assert proc.returncode == 0, out
    return proc.pid


def start_head(groups, cpus, dashboard_port=None):
    port = free_port()
    temp = tempfile.mkdtemp(prefix="rt", dir="/tmp")  # Unix socket paths must stay under 108 bytes
    groups.temp_dirs.append(temp)
    args = ["--head", f"--port={port}", f"--num-cpus={cpus}", f"--temp-dir={temp}",
            "--disable-usage-stats"]
    if dashboard_port:
        # Its own agent port too: another Ray on this machine may hold the default one.
        args += ["--include-dashboard=true", "--dashboard-host=127.0.0.1", f"--dashboard-port={dashboard_port}",
                 f"--dashboard-agent-listen-port={free_port()}"]
    else:
        args += ["--include-dashboard=false"]
    pid = ray_start(groups, *args)
    return f"127.0.0.1:{port}", pid


def test_driver_sigkill_then_rerun_equals_uninterrupted(groups, config_path, in_process_games, tmp_path):
    """`farm sweep` on a local Ray of its own SIGKILLed with its Ray once it has stored shards; the
    same command again, in process (--no-ray: the shards it stores are the same, and no second Ray
    starts), plays only the shards not stored, to the uninterrupted games."""
    out = tmp_path / "out"
    farm = [sys.executable, "-m", "farm.cli", "sweep", str(config_path), "--out", str(out), "--quiet"]
    with ray_start_lock():  # its local Ray starts, and is up once it stores shards
        driver = groups.popen([*farm, "--workers", "2"])
        try:
            wait_for_shards(out, 4, driver)
        except AssertionError as e:  # a local Ray that did not come up on a loaded machine: once more
            if "ended early" not in str(e) or (out / "shards").exists() and any((out / "shards").iterdir()):
                raise
            print(e)
            driver = groups.popen([*farm, "--workers", "2"])
            wait_for_shards(out, 4, driver)
    groups.kill(driver.pid)  # the driver and the local Ray it started
    driver.wait(timeout=60)
    stored = len(list((out / "shards").glob("*.parquet")))
    assert 4 <= stored < 32
    rerun = subprocess.run([*farm, "--no-ray"], env=ENV, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stderr
    runs = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert runs[-1]["skipped"] >= stored and runs[-1]["done"] == 32 - runs[-1]["skipped"]
    got = SweepRun(load_sweep_config(config_path), out).read_games()
    pd.testing.assert_frame_equal(got, in_process_games)


def test_two_node_cluster_survives_losing_a_node(groups, config_path, in_process_games, tmp_path):
    """A sweep on a head and a second node (1 CPU each); the second node SIGKILLed while one of
    its workers plays a shard: the sweep finishes, every shard once, with the in-process games.
    The head's shard workers are held stopped until the second node's worker plays a shard (on a
    loaded machine the head played all 32 before the second node's worker started); whether
    the second node stored shards before it died is not asserted."""
    address, head_session = start_head(groups, cpus=1)
    second = ray_start(groups, f"--address={address}", "--num-cpus=1")
    out = tmp_path / "out"
    driver = groups.popen([sys.executable, "-m", "farm.cli", "sweep", str(config_path), "--out", str(out),
                           "--address", address, "--workers", "2", "--quiet"])
    deadline = time.time() + 180
    held = set()  # the head's shard workers, stopped until the second node plays a shard
    try:
        while not any(cmdline(pid).startswith(b"ray::_remote_shard") for pid in session(second)):
            assert time.time() < deadline and driver.poll() is None, "the second node ran no shard"
            head = {p for p in session(head_session) if cmdline(p).startswith(b"ray::_remote_shard")}
            signal_all(head - held, signal.SIGSTOP)  # on a loaded machine the head played all 32 first
            held |= head
            time.sleep(0.02)
        signal_all(session(second), signal.SIGKILL)  # the second node (its raylet and workers) mid-shard
    finally:
        signal_all(held, signal.SIGCONT)
    text, _ = driver.communicate(timeout=600)
    assert driver.returncode == 0, text
    run = json.loads((out / "runs.jsonl").read_text().splitlines()[-1])
    assert run["done"] == 32 and sum(run["nodes"].values()) == 32
    got = SweepRun(load_sweep_config(config_path), out).read_games()
    pd.testing.assert_frame_equal(got, in_process_games)


RUNTIME_ENV = '{"excludes": ["workers/", "farm/"]}'  # the installed, precompiled package runs


@pytest.fixture(scope="module")
def job_head():
    """A 2-CPU head with its dashboard (the job server) on loopback, shared by the `ray job
    submit` tests (each job's actors end with it): (the job server's URL, the head's address)."""
    g = Groups()
    try:
        dashboard = free_port()
        address, _ = start_head(g, cpus=2, dashboard_port=dashboard)
        yield f"http://127.0.0.1:{dashboard}", address
    finally:
        g.close()


def ray_job(url, *args, timeout=60):
    """`ray job <args> --address url` (its stdout and stderr)."""
    return subprocess.run([str(BIN / "ray"), "job", args[0], "--address", url, *args[1:]], cwd=REPO, env=ENV,
                          capture_output=True, text=True, timeout=timeout)


def submit_and_wait(url, job_id, *command, timeout=300) -> tuple[str, str]:
    """`ray job submit` of `farm <command>` from the repository (--working-dir . with
    RUNTIME_ENV), `ray job status` polled until it ends; returns (status, logs)."""
    deadline = time.time() + 120
    while True:  # the head's job agent may need a moment after `ray start` on a loaded machine
        submit = ray_job(url, "submit", "--working-dir", ".", "--runtime-env-json", RUNTIME_ENV, "--submission-id",
                         job_id, "--no-wait", "--", "farm", *command, timeout=300)
        if submit.returncode == 0 or "No available agent" not in submit.stderr or time.time() > deadline:
            break
        time.sleep(2)
    assert submit.returncode == 0, submit.stdout + submit.stderr
    deadline, status = time.time() + timeout, ""
    while time.time() < deadline:
        status = ray_job(url, "status", job_id).stdout.upper()
        if any(s in status for s in ("SUCCEEDED", "FAILED", "STOPPED")):
            break
        time.sleep(1)
    return status, ray_job(url, "logs", job_id).stdout


def test_ray_job_submit_smoke_sweep(job_head, tmp_path):
    url, _ = job_head
    out = tmp_path / "job-out"
    status, logs = submit_and_wait(url, f"sweep-{os.getpid()}", "sweep", "configs/smoke.yaml", "--out", str(out),
                                   "--quiet")
    assert "SUCCEEDED" in status, status + logs
    assert "smoke: 4 point(s), 160 games" in logs
    summary = pd.read_parquet(out / "summary.parquet")
    assert len(summary) == 4 and (summary["n_games"] == 40).all()
    run = json.loads((out / "runs.jsonl").read_text().splitlines()[-1])
    assert run["workers"] == 2 and run["done"] == 16


def test_ray_job_submit_smoke_experiment(job_head, tmp_path):
    """`farm experiments` as a job: the smoke experiment's second point, one seed of 300 steps,
    its store in tmp_path, its base config read from the job's working dir; the driver joins
    the head ($RAY_ADDRESS) and its service actor and trials run there."""
    from ray.util.state import list_actors

    url, _ = job_head
    from farm.service.actor import SERVICE_NAME

    raw = yaml.safe_load((REPO / "configs" / "experiments" / "smoke.yaml").read_text())
    raw.update(name="job-smoke", grid={"env.c_capture": [1.5]}, seeds=[0], store=str(tmp_path / "store.sqlite"))
    config = tmp_path / "experiment.yaml"
    config.write_text(yaml.safe_dump(raw))
    out = tmp_path / "job-out"
    status, logs = submit_and_wait(url, f"experiment-{os.getpid()}", "experiments", str(config), "--out",
                                   str(out), "--quiet")
    assert "SUCCEEDED" in status, status + logs
    assert "job-smoke: 1/1 trial(s) finished (0 before this run), 1 at once at 1 CPU each on 2 CPUs" in logs
    assert f"wrote {out / 'trials.csv'}" in logs
    trials = pd.read_csv(out / "trials.csv")
    assert trials["trial"].tolist() == ["p0_s0"] and trials["seed"].tolist() == [0]
    assert np.isfinite(trials["learned_return"]).all() and (trials["timesteps"] == 300).all()
    summary = pd.read_csv(out / "summary.csv")
    assert summary["seeds"].tolist() == [1] and np.isfinite(summary["return_mean"]).all()
    services = list_actors(address=url, filters=[("name", "=", SERVICE_NAME)], raise_on_missing_output=False)
    assert len(services) == 1, services  # the experiment's service ran on the head, not on a Ray of its own


def test_a_local_command_runs_on_a_ray_of_its_own_beside_a_ray_start_cluster_and_its_stale_pointer(groups, tmp_path):
    """`ray start --head` on this machine writes Ray's pointer file, /tmp/ray/ray_current_cluster,
    which ray.init() without an address follows. A command given no address starts its own
    local Ray all the same: beside the running cluster (whose state API then lists no job or
    task of it), and again once that cluster is killed and only its stale pointer is left."""
    pointer = Path("/tmp/ray/ray_current_cluster")
    before = pointer.read_text() if pointer.exists() else None
    port, dashboard = free_port(), free_port()
    config = write_sweep(tmp_path / "sweep.yaml", games_per_point=8, shard_games=4)
    env = {k: v for k, v in ENV.items() if k != "RAY_ADDRESS"}

    def sweep(out):
        with ray_start_lock():  # its own local Ray
            r = subprocess.run([sys.executable, "-m", "farm.cli", "sweep", str(config), "--out", str(tmp_path / out),
                                "--workers", "1", "--quiet"], env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        return pd.read_parquet(tmp_path / out / "summary.parquet")

    def listed(kind):
        """What the other cluster's state API (its dashboard) lists of a kind, once it answers."""
        deadline = time.time() + 120
        while True:
            r = subprocess.run([str(BIN / "ray"), "list", kind, "--address", f"http://127.0.0.1:{dashboard}",
                                "--format", "json"], env=env, capture_output=True, text=True, timeout=60)
            if r.returncode == 0 or time.time() > deadline:
                break
            time.sleep(2)
        assert r.returncode == 0, r.stdout + r.stderr
        if r.stdout.strip() == "No resource in the cluster":  # what `ray list` prints for none
            return []
        return json.loads(r.stdout[r.stdout.index("["):])

    try:
        ray_start(groups, "--head", f"--port={port}", "--num-cpus=1", "--include-dashboard=true",
                  "--dashboard-host=127.0.0.1", f"--dashboard-port={dashboard}",
                  f"--dashboard-agent-listen-port={free_port()}", "--disable-usage-stats")
        assert pointer.read_text().strip().endswith(f":{port}")
        beside = sweep("beside")
        assert listed("jobs") == [] and listed("tasks") == []
        groups.close()  # the cluster is killed; its pointer file stays behind
        assert pointer.read_text().strip().endswith(f":{port}")
        pd.testing.assert_frame_equal(sweep("stale"), beside)
    finally:
        if before is None:
            pointer.unlink(missing_ok=True)
        else:
            pointer.write_text(before)


# ----- joining a head on this machine by every address form a user has: the address the head
# advertises (this machine's), 127.0.0.1, localhost, $RAY_ADDRESS and `auto`; `farm exploit` and
# `farm robust` by 127.0.0.1 and by $RAY_ADDRESS; a process on one head asked for another refused.

# Connects as a command does (ray_cluster, then ray_cluster again inside it, as a command's
# capture-time client does) and prints the cluster it is connected to.
JOIN = textwrap.dedent("""
    import sys
    from farm.core.errors import SwarmFarmError
    from farm.runtime import ray_cluster
    address = sys.argv[1] if len(sys.argv) > 1 else None
    try:
        with ray_cluster(address) as ray:
            with ray_cluster(sys.argv[2] if len(sys.argv) > 2 else address) as again:
                print(again.get_runtime_context().gcs_address)
    except SwarmFarmError as e:
        print(f"error: {e}")
""")


def start_advertising_head(groups: Groups) -> int:
    """A 2-CPU head on this machine, advertising the machine's own address as Ray chooses
    (no --node-ip-address); its GCS port."""
    port = free_port()
    temp = tempfile.mkdtemp(prefix="rt", dir="/tmp")
    groups.temp_dirs.append(temp)
    with ray_start_lock():
        proc = groups.popen([str(BIN / "ray"), "start", "--head", f"--port={port}", "--num-cpus=2",
                             f"--temp-dir={temp}", "--include-dashboard=false", "--disable-usage-stats"])
        out, _ = proc.communicate(timeout=180)
    assert proc.returncode == 0, out
    return port


@pytest.fixture(scope="module")
def head():
    """The head's port and the address it advertises (host:port)."""
    g = Groups()
    try:
        port = start_advertising_head(g)
        said = subprocess.run([sys.executable, "-c", "import ray, sys; ray.init(address=sys.argv[1]); "
                               "print(ray.get_runtime_context().gcs_address)", f"127.0.0.1:{port}"],
                              env=ENV, capture_output=True, text=True, timeout=180)
        advertised = said.stdout.strip().splitlines()[-1]
        assert advertised.endswith(f":{port}"), said.stdout + said.stderr
        yield port, advertised
    finally:
        g.close()


def join(*args: str, env: dict | None = None) -> str:
    """JOIN's one line: the cluster joined, or `error: ...`."""
    out = subprocess.run([sys.executable, "-c", JOIN, *args], cwd=REPO, env=env or ENV, capture_output=True,
                         text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def farm_command(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "farm"), *args], cwd=REPO, env=env or ENV, capture_output=True, text=True,
                          timeout=600)


def test_every_address_form_joins_the_same_head(head):
    port, advertised = head
    if advertised.startswith("127.0.0.1:"):
        pytest.skip("this machine's Ray advertises 127.0.0.1: no second address to join by")
    assert join(advertised) == advertised
    assert join(f"127.0.0.1:{port}") == advertised
    assert join(f"localhost:{port}") == advertised
    assert join(env={**ENV, "RAY_ADDRESS": f"127.0.0.1:{port}"}) == advertised
    # auto: the head this machine's pointer file names (the newest `ray start`); with RAY_ADDRESS
    # set, Ray takes that one, as ray.init does.
    assert join("auto", env={**ENV, "RAY_ADDRESS": f"127.0.0.1:{port}"}) == advertised


def test_a_process_on_one_head_asked_for_another_is_refused_in_one_line(head, job_head):
    port, advertised = head
    _, other = job_head  # the job tests' head: another cluster on this machine
    said = join(f"127.0.0.1:{port}", other)
    assert said == (f"error: address {other}: this process is already connected to the Ray "
                    f"cluster at {advertised}")


def test_exploit_and_robust_join_by_loopback_and_by_ray_address(head, tmp_path):
    port, _ = head
    r = farm_command("exploit", "spread_evenly", "--scenario", "outnumbered_3x3", "--seeds", "none", "--episodes", "2",
             "--exact", "never", "--address", f"127.0.0.1:{port}", "--out", str(tmp_path / "exploit"), "--quiet")
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "exploit" / "table.csv").exists()
    config = tmp_path / "robust.yaml"
    config.write_text(yaml.safe_dump({
        "name": "robust_join", "scenario": "outnumbered_3x3", "allocators": ["spread_evenly"],
        "intruders": ["drift"], "iterations": 1, "payoffs": {"episodes": 2, "seed": 2000}, "oracle": "library",
        "library": {"allocators": ["intercept"], "intruders": ["fewest_ahead"]}, "distill": None, "exact": "never",
        "store": str(tmp_path / "capture_times.sqlite")}))
    r = farm_command("robust", str(config), "--out", str(tmp_path / "robust"), "--quiet",
             env={**ENV, "RAY_ADDRESS": f"127.0.0.1:{port}"})
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "robust" / "robust.json").exists()
