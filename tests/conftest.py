import contextlib
import os
import socket
from pathlib import Path

# Every local Ray of the tests binds 127.0.0.1 (farm.runtime's module doc): Ray reads this when imported.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")

import yaml

import numpy as np
import pytest

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
HEXAGON = np.array([[5 + 5 * np.cos(a), 5 + 5 * np.sin(a)] for a in np.arange(6) * np.pi / 3])
TRIANGLE = np.array([[0.0, 0.0], [10.0, 0.0], [3.0, 8.0]])


def points_in(arena_vertices, shape, rng):
    from workers import make_arena

    return make_arena(arena_vertices).sample_uniform(rng, shape)


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


def write_sweep(path, **changes):
    """A small sweep config (2 x 2 points of area_min games, 2 evaders) written to path,
    top-level fields replaced by `changes`; returns path."""
    config = {"name": "ray-test", "seed": 7, "games_per_point": 24, "shard_games": 6,
              "base": {"n_evaders": 2, "t_max": 20},
              "vary": {"grid": {"n_pursuers": [2, 4], "evader_policy": ["centroid", "constant_area"]}}}
    path.write_text(yaml.safe_dump({**config, **changes}, sort_keys=False))
    return path


def session(sid: int) -> list[int]:
    """The pids of the processes in session sid (a driver started with start_new_session: it,
    its local Ray and the Ray's workers, which have process groups of their own)."""
    pids = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            with contextlib.suppress(OSError, IndexError, ValueError):
                # /proc/PID/stat: "pid (comm) state ppid pgrp session ...", comm may hold spaces
                if int((proc / "stat").read_text().rsplit(")", 1)[1].split()[3]) == sid:
                    pids.append(int(proc.name))
    return pids


def signal_all(pids, signum: int) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signum)
