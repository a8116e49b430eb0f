import contextlib
import os
import socket
from pathlib import Path

# Every local Ray of the tests binds 127.0.0.1 (farm.runtime's module doc): Ray reads this when imported.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")

# Under `make test`'s 2 xdist workers, each test process (and the `farm` subprocesses and Ray
# it starts, which inherit this) runs torch's and BLAS's thread pools on one thread: two
# processes of two spinning threads each on 2 cores made a torch fit 7x slower than alone.
# Read when torch and numpy load, so before any import of either.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_threads, "1")

import yaml

import numpy as np
import pytest

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
HEXAGON = np.array([[5 + 5 * np.cos(a), 5 + 5 * np.sin(a)] for a in np.arange(6) * np.pi / 3])
TRIANGLE = np.array([[0.0, 0.0], [10.0, 0.0], [3.0, 8.0]])


def points_in(arena_vertices, shape, rng):
    from workers import make_arena

    return make_arena(arena_vertices).sample_uniform(rng, shape)


# `make test` runs the suite on 2 pytest-xdist workers (--dist loadgroup). The modules below
# start no Ray (their `farm` commands run in process: --no-ray, service.mode local): each is a
# group of its own (its module fixtures made once), spread over both workers. Every other
# module starts or joins Ray, in this process or through `farm` and `ray` subprocesses; they
# form one group and so run one after another on one worker, as without xdist: two Rays
# starting at once on 2 cores can miss Ray's 30 s start deadline.
WITHOUT_RAY = {"test_experiment_storage", "test_alloc_env", "test_animate", "test_report", "test_alloc_td3", "test_alloc_train", "test_alloc_v2", "test_capture_score", "test_cell_policy",
               "test_claims", "test_cli", "test_compiled", "test_docs", "test_docstrings", "test_engine", "test_env_api",
               "test_escapes", "test_estimates_rule", "test_farm_layout", "test_geometry", "test_global_state", "test_learners", "test_montecarlo",
               "test_planners", "test_policy_registry", "test_reference_selfcheck", "test_refuses_cli", "test_refuses_configs", "test_refuses_probe", "test_refuses_shards",
               "test_refuses_training", "test_refuses_workers", "test_resume_damaged", "test_size_free", "test_sweep_config", "test_tracking", "test_train_resume", "test_vector_env",
               "test_workers_layout"}


# Modules of the Ray group whose Ray tests all take the ray_local fixture: their other tests
# start no Ray, and run beside the Ray group as a group of their own (the Ray group is the
# suite's critical path).
MIXED = {"test_refuses_store", "test_service", "test_suite", "test_sweep_ray", "test_runtime", "test_live_engagements", "test_pretrain_ray", "test_dashboards"}


def _without_ray(item) -> bool:
    """Whether a test starts no Ray: its module is WITHOUT_RAY, or MIXED and it takes no ray_local."""
    module = Path(str(item.fspath)).stem
    return module in WITHOUT_RAY or (module in MIXED and "ray_local" not in getattr(item, "fixturenames", ()))


@pytest.hookimpl(tryfirst=True)  # before xdist's hook, which reads the groups
def pytest_collection_modifyitems(items):
    for item in items:
        module = Path(str(item.fspath)).stem
        group = "ray" if not _without_ray(item) else module if module in WITHOUT_RAY else f"{module}-without-ray"
        item.add_marker(pytest.mark.xdist_group(group))


@pytest.fixture(autouse=True)
def _without_ray_means_without_ray(request, monkeypatch):
    """A test that starts no Ray (_without_ray) and would start or join Ray fails instead of
    running beside the Ray group: $RAY_ADDRESS names a closed port, which every `farm` command
    and farm.runtime.ray_cluster would try to join."""
    if _without_ray(request.node):
        monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")


@pytest.fixture
def rng():
    return np.random.default_rng(20261123)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_local():
    """A real 2-CPU local Ray for one test module (farm.runtime.ray_cluster, metrics reported
    every 0.5 s through Ray's RAY_<setting> environment); yields its Prometheus metrics port."""
    from farm.runtime import ray_cluster

    port = free_port()
    before = os.environ.get("RAY_metrics_report_interval_ms")
    os.environ["RAY_metrics_report_interval_ms"] = "500"
    try:
        with ray_cluster(num_cpus=2, metrics_port=port, dashboard=False):
            yield port
    finally:
        if before is None:
            os.environ.pop("RAY_metrics_report_interval_ms", None)
        else:
            os.environ["RAY_metrics_report_interval_ms"] = before


S3_ENV = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1",
          "AWS_EC2_METADATA_DISABLED": "true"}


@contextlib.contextmanager
def s3_bucket(name: str = "farm"):
    """An S3-compatible server on localhost (moto's server mode, in a thread) holding an empty
    bucket `name`, its endpoint and test credentials in the environment (AWS_ENDPOINT_URL,
    AWS_ACCESS_KEY_ID, …: pyarrow's, so Ray Tune's, and boto3's) for the block, so a Ray
    started inside it passes them to its workers; yields a boto3 client of the server."""
    import logging

    import boto3
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=free_port())
    server.start()
    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # a line per request otherwise
    host, port = server.get_host_and_port()
    env = {**S3_ENV, "AWS_ENDPOINT_URL": f"http://{host}:{port}"}
    before = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        client = boto3.client("s3")
        client.create_bucket(Bucket=name)
        yield client
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        server.stop()


def bucket_keys(client, bucket: str = "farm", prefix: str = "") -> list[str]:
    """Every object key under prefix in the bucket, sorted."""
    pages = client.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix)
    return sorted(o["Key"] for page in pages for o in page.get("Contents", []))


def write_sweep(path, **changes):
    """A small sweep config (2 x 2 points of area_min games, 2 evaders) written to path,
    top-level fields replaced by `changes`; returns path."""
    config = {"name": "ray-test", "seed": 7, "games_per_point": 24, "shard_games": 6,
              "base": {"n_evaders": 2, "t_max": 20},
              "vary": {"grid": {"n_pursuers": [2, 4], "evader_policy": ["centroid", "constant_area"]}}}
    path.write_text(yaml.safe_dump({**config, **changes}, sort_keys=False))
    return path


def processes() -> list[int]:
    """The pids of this machine's processes (Linux's /proc)."""
    return [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()]


def cmdline(pid: int) -> bytes:
    """A process's title (its command line; a Ray worker's is "ray::<task>" while it runs
    one), b"" for a process gone or not ours to look into."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def session(sid: int) -> list[int]:
    """The pids of the processes in session sid (a driver started with start_new_session: it,
    its local Ray and the Ray's workers, which have process groups of their own)."""
    pids = []
    for pid in processes():
        with contextlib.suppress(OSError, IndexError, ValueError):
            # /proc/PID/stat: "pid (comm) state ppid pgrp session ...", comm may hold spaces
            if int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[3]) == sid:
                pids.append(pid)
    return pids


def signal_all(pids, signum: int) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signum)


def farm_main(*argv):
    """farm.cli.main in this process: (exit status, stdout, stderr)."""
    import contextlib
    import io

    from farm.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main([str(a) for a in argv])
        except SystemExit as e:
            status = e.code
    return status, out.getvalue(), err.getvalue()


def train_tiny_run(root: Path, extra: str = "") -> Path:
    """A tiny TD3 run (3x3, 120 steps, service in process, its store in root) trained into
    root/run by `farm train`; extra: more config lines. Returns the run folder."""
    config = root / "tiny.yaml"
    config.write_text(f"name: tiny\nseed: 0\nenv: {{grid_size: 3, n_defenders: 10, n_intruders: 5, games: 3, "
                      f"c_distribution: 1.0, c_capture: 1.5}}\ntd3: {{n_timesteps: 120, learning_starts: 60, "
                      f"batch_size: 32, buffer_size: 1000}}\nservice: {{mode: local, store: {root / 'store.sqlite'}}}\n"
                      + extra)
    status, out, err = farm_main("train", config, "--out", root / "run")
    assert status == 0, err
    return root / "run"
