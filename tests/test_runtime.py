"""One runtime: every start or join of Ray through farm.runtime, conflicts refused in one
line, the service bound to its store, one bounded-submit helper, --debug tracebacks."""

import os
import subprocess
import sys
import threading

import pytest

from farm.core.errors import ClusterError, ConfigError
from farm.runtime import bounded, ray_cluster, task_result


@pytest.mark.ray
def test_asking_the_running_ray_for_what_it_does_not_have_is_one_line(ray_local):
    import ray

    with ray_cluster(num_cpus=2, metrics_port=ray_local) as r:  # what it has: no error
        assert r is ray
    gcs = ray.get_runtime_context().gcs_address
    with ray_cluster(address=gcs):
        pass
    for kwargs, field in (({"num_cpus": 3}, "num_cpus: 3"), ({"metrics_port": ray_local + 1}, "metrics_port"),
                          ({"address": "127.0.0.1:1"}, "address 127.0.0.1:1")):
        with pytest.raises(ClusterError) as e:
            with ray_cluster(**kwargs):
                pass
        assert str(e.value).startswith(field) and "\n" not in str(e.value)
    assert ray.is_initialized()  # a refusal leaves the running Ray alone


@pytest.mark.ray
def test_get_service_refuses_an_actor_that_serves_another_store(ray_local, tmp_path):
    from farm.service import get_service

    a = get_service(tmp_path / "a.sqlite", name="svc-store-check")
    assert get_service(tmp_path / "a.sqlite", name="svc-store-check")._actor_id == a._actor_id
    with pytest.raises(ConfigError) as e:
        get_service(tmp_path / "b.sqlite", name="svc-store-check")
    msg = str(e.value)
    assert msg.startswith("store:") and "a.sqlite" in msg and "b.sqlite" in msg and "\n" not in msg



@pytest.mark.ray
def test_a_client_block_stops_the_service_it_made_so_the_next_block_may_name_another_store(ray_local, tmp_path):
    # CI's failure (stop 43): a handle left in a reference cycle kept the first block's service
    # alive until a garbage collection, and the next block, naming another store, was refused.
    import gc

    import ray

    from farm.service import GameSettings
    from farm.service.actor import SERVICE_NAME, _running, get_service
    from farm.service.client import open_client

    gc.disable()
    try:
        with open_client(GameSettings(), store=tmp_path / "a.sqlite") as client:
            cycle = [client]
            cycle.append(cycle)
        assert not _running(SERVICE_NAME)
        with open_client(GameSettings(), store=tmp_path / "b.sqlite") as client:
            assert ray.get(client.backend.actor.store_path.remote()) == str((tmp_path / "b.sqlite").resolve())
        # a service running before the block (an outer one's) is left running
        outer = get_service(tmp_path / "c.sqlite")
        with open_client(GameSettings(), store=tmp_path / "c.sqlite"):
            pass
        assert _running(SERVICE_NAME)
        ray.kill(outer, no_restart=True)
    finally:
        del cycle
        gc.enable()


@pytest.mark.ray
def test_bounded_keeps_at_most_the_limit_in_flight_also_across_threads(ray_local):
    import ray

    @ray.remote(num_cpus=0)
    class Gauge:
        def __init__(self):
            self.now, self.top = 0, 0

        def enter(self):
            self.now += 1
            self.top = max(self.top, self.now)

        def leave(self):
            self.now -= 1

        def peak(self):
            return self.top

    gauge = Gauge.remote()

    @ray.remote(num_cpus=0)
    def work(x):
        import time

        ray.get(gauge.enter.remote())
        time.sleep(0.05)
        ray.get(gauge.leave.remote())
        return x * x

    got = {item: ray.get(ref) for item, ref in bounded(lambda x: work.remote(x), range(12), 3)}
    assert got == {x: x * x for x in range(12)} and ray.get(gauge.peak.remote()) <= 3

    gauge = Gauge.remote()
    slots = threading.BoundedSemaphore(2)
    results = []

    def run(offset):
        results.extend(ray.get(ref) for _, ref in bounded(lambda x: work.remote(x), range(offset, offset + 6), 2,
                                                          slots=slots))

    threads = [threading.Thread(target=run, args=(k * 10,)) for k in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert sorted(results) == sorted(x * x for k in range(3) for x in range(k * 10, k * 10 + 6))
    assert ray.get(gauge.peak.remote()) <= 2


@pytest.mark.ray
def test_task_result_is_a_tasks_value_or_its_project_error_in_one_line(ray_local):
    """A project error a task raised comes back as itself, its line prefixed with where it came from;
    any other error as Ray raises it."""
    import ray

    @ray.remote(num_cpus=0)
    def task(outcome: str):
        if outcome == "project":
            raise ConfigError("episodes: too many")
        if outcome == "other":
            raise ValueError("not the project's")
        return 3

    assert task_result(task.remote("value"), "episode seed 7") == 3
    with pytest.raises(ConfigError) as e:
        task_result(task.remote("project"), "episode seed 7")
    assert str(e.value) == "episode seed 7: episodes: too many" and not isinstance(e.value, ray.exceptions.RayError)
    with pytest.raises(ray.exceptions.RayTaskError, match="not the project's"):
        task_result(task.remote("other"), "episode seed 7")


def _farm(*args, env=None):
    return subprocess.run([sys.executable, "-m", "farm.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300, env={**os.environ, **(env or {})})


@pytest.mark.slow
def test_debug_shows_the_traceback_else_one_line(tmp_path):
    bad = tmp_path / "nope.yaml"
    plain = _farm("sweep", bad)
    assert plain.returncode == 2 and plain.stderr.strip().count("\n") == 0 and "Traceback" not in plain.stderr
    for r in (_farm("--debug", "sweep", bad), _farm("sweep", bad, env={"SWARM_FARM_DEBUG": "1"})):
        assert r.returncode != 0 and "Traceback" in r.stderr and "ConfigError" in r.stderr


def test_library_errors_name_fields_and_the_cli_names_flags(tmp_path):
    from farm.games.sweep import load_sweep_config
    from farm.games.sweep.run import SweepRun

    config = tmp_path / "s.yaml"
    config.write_text("name: s\ngames_per_point: 4\nbase: {n_pursuers: 1, n_evaders: 1, t_max: 2, tau: 2}\n")
    taken = tmp_path / "file"
    taken.write_text("x")
    with pytest.raises(ConfigError, match=r"^out: "):
        SweepRun(load_sweep_config(config), taken).prepare()
    r = _farm("sweep", config, "--out", taken, "--no-ray")
    assert r.returncode == 2 and r.stderr.startswith("farm: error: --out: ")


@pytest.mark.ray
@pytest.mark.slow
def test_the_local_ray_is_on_loopback_and_starts_quietly(ray_local, tmp_path):
    import ray

    assert {n["NodeManagerAddress"] for n in ray.nodes() if n["Alive"]} == {"127.0.0.1"}
    assert ray.get_runtime_context().gcs_address.startswith("127.0.0.1:")
    config = tmp_path / "s.yaml"
    config.write_text("name: quiet\ngames_per_point: 4\nshard_games: 2\n"
                      "base: {n_pursuers: 1, n_evaders: 1, t_max: 2, tau: 2}\n")
    r = _farm("sweep", config, "--out", tmp_path / "out", "--quiet", "--workers", 1)
    assert r.returncode == 0, r.stderr
    assert "WARNING" not in r.stderr and "Token authentication" not in r.stderr, r.stderr
