import collections
import contextlib
import fcntl
import os
import signal
import socket
import subprocess
import tempfile
import time
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

import numpy as np
import pytest
import yaml

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
HEXAGON = np.array([[5 + 5 * np.cos(a), 5 + 5 * np.sin(a)] for a in np.arange(6) * np.pi / 3])
TRIANGLE = np.array([[0.0, 0.0], [10.0, 0.0], [3.0, 8.0]])


def points_in(arena_vertices, shape, rng):
    from workers import make_arena

    return make_arena(arena_vertices).sample_uniform(rng, shape)


# The suite's marks (pyproject.toml's [tool.pytest.ini_options]), on the tests themselves
# (a module's `pytestmark` when all its tests are one kind, else a decorator per test):
#   ray      the test starts or joins a Ray: it takes ray_local (the shared local Ray), or it is
#            own_ray too.
#   own_ray  the test starts Rays of its own (`ray start` clusters, `farm` commands starting a
#            local Ray, ray_own: one in its process), each under ray_start_lock, and never joins
#            the shared one.
#   slow     the test takes more than about 5 s (`--durations=0`), its module fixtures included.
# `make test-fast` runs the tests neither ray nor slow; `make test` runs them all.
#
# `make test` runs the suite on 3 pytest-xdist workers on 2 cores (--dist loadgroup: a group's
# tests on one worker; --no-loadscope-reorder: the groups handed out in the order of the items
# below): a third worker fills the time the tests wait on Ray starts, process spawns and polls.
# The tests on a shared Ray are two groups, first, by module
# (SECOND_SHARED_RAY: about half the shared tests' time, by `--durations=0`): each runs one test
# after another on one worker, on one Ray start of that worker's own, and they are the suite's
# critical path. The own_ray tests are a group of their own, third, so the third worker starts on
# it beside them. Two Rays starting at once on 2 cores can miss Ray's 30 s start deadline, so every
# shared Ray and every own_ray Ray start under ray_start_lock, one at a time across the workers;
# and a test that signals or kills Ray workers picks them among its own process's descendants
# (descendants), never another worker's. Every other test starts no Ray: a module's such tests are
# a group of their own (its module fixtures made once), spread over the workers, the groups with
# the most slow tests first, then the largest, so that no long group is left for the end. A test
# not marked ray runs with $RAY_ADDRESS naming a closed port (_not_ray_means_no_ray), so that it
# fails if it starts or joins Ray after all.
SHARED_RAY, SECOND_RAY, OWN_RAY = "ray", "ray-2", "own-ray"  # the groups of the ray tests
SECOND_SHARED_RAY = {"test_experiments", "test_runtime", "test_live_engagements", "test_exploit",
                     "test_move_helpers", "test_pretrain_ray", "test_service"}  # modules on the second shared Ray


def _marked(item, name: str) -> bool:
    return item.get_closest_marker(name) is not None


def _takes_ray_local(item) -> bool:
    return "ray_local" in getattr(item, "fixturenames", ())


def _mark_error(item) -> str | None:
    """What is wrong with a test's ray and own_ray marks (the comment above), None if nothing."""
    ray, own, shared = _marked(item, "ray"), _marked(item, "own_ray"), _takes_ray_local(item)
    if shared and not ray:
        return "takes ray_local but is not marked ray"
    if own and not ray:
        return "is marked own_ray but not ray"
    if own and shared:
        return "is marked own_ray but takes the shared ray_local"
    if ray and not (own or shared):
        return "is marked ray but neither takes ray_local nor is marked own_ray"
    if "ray_own" in getattr(item, "fixturenames", ()) and not own:
        return "takes ray_own but is not marked own_ray"
    return None


@pytest.hookimpl(tryfirst=True)  # before its fixtures are set up: no Ray started for it
def pytest_runtest_setup(item):
    """A test whose ray marks do not say what it does fails in its setup, naming the mistake."""
    error = _mark_error(item)
    if error is not None:
        pytest.fail(f"{item.nodeid} {error} (tests/conftest.py's marks)", pytrace=False)


def _group(item) -> str:
    module = Path(str(item.fspath)).stem
    if not _marked(item, "ray"):
        return module
    if _marked(item, "own_ray"):
        return OWN_RAY
    return SECOND_RAY if module in SECOND_SHARED_RAY else SHARED_RAY


@pytest.hookimpl(tryfirst=True)  # before xdist's hook, which reads the groups, and before -m deselects
def pytest_collection_modifyitems(config, items):
    groups = {item.nodeid: _group(item) for item in items}
    if config.pluginmanager.hasplugin("xdist"):  # its mark, unknown without it (-p no:xdist)
        for item in items:
            item.add_marker(pytest.mark.xdist_group(groups[item.nodeid]))
    sizes = collections.Counter(groups.values())
    slow = collections.Counter(groups[item.nodeid] for item in items if _marked(item, "slow"))
    first = {SHARED_RAY: 0, SECOND_RAY: 1, OWN_RAY: 2}

    # The shared Rays' groups, then the own_ray group, then the others, the most slow tests first,
    # then the largest (as xdist's own --loadscope-reorder would). The sort is stable: a group's
    # tests stay in the order of their module, which ray_local's one Ray start relies on.
    def order(item):
        group = groups[item.nodeid]
        return (first.get(group, 3), -slow[group], -sizes[group], group)

    items.sort(key=order)


RAY_START_LOCK = Path(tempfile.gettempdir()) / "swarm-farm-tests-ray-start.lock"


@contextlib.contextmanager
def ray_start_lock():
    """Held while a test starts a Ray (the shared one, a `ray start` node, a `farm` command
    starting its own): one start at a time across the xdist workers (the module doc)."""
    with open(RAY_START_LOCK, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def descendants() -> list[int]:
    """The pids of this process's descendants: the shared Ray's processes (its workers among
    them) and the subprocesses this test started, but no other xdist worker's."""
    import psutil

    return [p.pid for p in psutil.Process().children(recursive=True)]


_NEXT = {}  # the item that runs after the one being torn down (pytest_runtest_teardown)


@pytest.hookimpl(tryfirst=True)  # before the fixtures' finalizers run
def pytest_runtest_teardown(item, nextitem):
    _NEXT["item"] = nextitem


@pytest.fixture(autouse=True)
def _not_ray_means_no_ray(request, monkeypatch):
    """A test not marked ray that would start or join Ray fails instead of running beside the
    Ray tests (or in `make test-fast`): $RAY_ADDRESS names a closed port, which every `farm`
    command and farm.runtime.ray_cluster would try to join."""
    if not _marked(request.node, "ray"):
        monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")


@pytest.fixture
def rng():
    return np.random.default_rng(20261123)


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """A capture-time store file of the module's own, made by the first client that opens it."""
    return tmp_path_factory.mktemp("store") / "store.sqlite"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _SharedRay:
    """One real 2-CPU local Ray (farm.runtime.ray_cluster, metrics reported every 0.5 s through
    Ray's RAY_<setting> environment) for the Ray group's modules that take ray_local, one after
    another: a Ray start costs about 8 s of CPU on 2 cores. It is started inside an S3 bucket
    `farm` (s3_bucket) so that its workers have the bucket's endpoint and credentials
    (tests/test_experiments.py's object storage). Between modules every named actor is killed
    and the Ray's CPUs are free again, as on a Ray of their own; it is shut down before any test
    that does not take ray_local (another group's, or one that starts a Ray of its own)."""

    def __init__(self):
        self.stack = None
        self.port = None
        self.s3 = None

    def start(self):
        if self.stack is not None:
            return
        from farm.runtime import ray_cluster

        stack = contextlib.ExitStack()
        try:
            self.s3 = stack.enter_context(s3_bucket("farm"))
            self.port = free_port()
            before = os.environ.get("RAY_metrics_report_interval_ms")
            os.environ["RAY_metrics_report_interval_ms"] = "500"
            stack.callback(lambda: os.environ.__setitem__("RAY_metrics_report_interval_ms", before)
                           if before is not None else os.environ.pop("RAY_metrics_report_interval_ms", None))
            with ray_start_lock():
                stack.enter_context(ray_cluster(num_cpus=2, metrics_port=self.port, dashboard=False))
        except BaseException:
            stack.close()
            raise
        self.stack = stack

    def clean(self):
        """Kill every named actor and wait (at most 60 s) until both CPUs are free."""
        import ray

        for actor in ray.util.list_named_actors(all_namespaces=True):
            with contextlib.suppress(Exception):  # gone already
                ray.kill(ray.get_actor(actor["name"], namespace=actor["namespace"]))
        deadline = time.monotonic() + 60
        while ray.available_resources().get("CPU", 0) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)

    def stop(self):
        if self.stack is not None:
            stack, self.stack, self.s3 = self.stack, None, None
            stack.close()


_SHARED_RAY = _SharedRay()


@pytest.fixture(scope="module")
def ray_local():
    """The shared local Ray (_SharedRay) for one test module, as clean as a Ray of its own;
    yields its Prometheus metrics port."""
    _SHARED_RAY.start()
    try:
        yield _SHARED_RAY.port
    finally:
        nextitem = _NEXT.get("item")
        if nextitem is not None and _takes_ray_local(nextitem):
            _SHARED_RAY.clean()
        else:
            _SHARED_RAY.stop()


@pytest.fixture
def ray_own():
    """A local Ray of the test's own in this process (farm.runtime.ray_cluster, 2 CPUs), started
    under ray_start_lock and shut down after the test: for an own_ray test whose in-process runs
    and `farm` drivers (joining its address) need one Ray beside the shared one's tests."""
    from farm.runtime import ray_cluster

    with contextlib.ExitStack() as stack:
        with ray_start_lock():
            stack.enter_context(ray_cluster(num_cpus=2, dashboard=False))
        yield


@pytest.fixture(scope="module")
def ray_s3(ray_local):
    """A boto3 client of the S3 server the shared Ray was started in (bucket `farm`)."""
    return _SHARED_RAY.s3


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


DEADLINE = 600  # seconds for a file to appear, generous for a loaded 2-core machine (the tests poll)


def ray_workers() -> list[int]:
    """The shared Ray's workers (this process's descendants: never another xdist worker's)."""
    return [pid for pid in descendants() if cmdline(pid).startswith(b"ray::")]


def holder(folder: Path) -> int | None:
    """The pid of a Ray worker of the shared Ray holding a file under folder open (Linux's
    /proc; a trial's worker holds its run's TensorBoard file while it trains), or None."""
    prefix = str(folder) + os.sep
    for pid in ray_workers():
        with contextlib.suppress(OSError):  # gone, or not ours to look into
            if any(os.readlink(fd).startswith(prefix) for fd in Path(f"/proc/{pid}/fd").iterdir()):
                return pid
    return None


def wait_for(what: str, ready, alive=lambda: True):
    """Poll ready() until it returns something true (returned), at most DEADLINE seconds, while alive()."""
    deadline = time.monotonic() + DEADLINE
    while time.monotonic() < deadline:
        value = ready()
        if value:
            return value
        if not alive():
            raise AssertionError(f"ended before {what}")
        time.sleep(0.05)
    raise AssertionError(f"no {what} within {DEADLINE} s")


def kill_session(process: subprocess.Popen) -> None:
    """SIGKILL a process started in a session of its own and every process of the session
    (its local Ray and the Ray's workers, in process groups of their own)."""
    signal_all(session(process.pid), signal.SIGKILL)  # the process itself among them
    process.wait(timeout=60)


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


@contextlib.contextmanager
def immutable(path: Path):
    """path made immutable (chattr +i: root cannot write it either; os.access says so); the test
    is skipped where chattr +i is not available."""
    r = subprocess.run(["chattr", "+i", str(path)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"chattr +i is not available here: {r.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["chattr", "-i", str(path)], check=True)
