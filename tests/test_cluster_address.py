"""Joining a `ray start --head` cluster on this machine by every address form a user has: the
address the head advertises (this machine's), 127.0.0.1, $RAY_ADDRESS and `auto`; `farm
exploit` and `farm robust` by 127.0.0.1 and by $RAY_ADDRESS; and a process connected to one head
refused, in one line, when asked for another."""

import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest
import yaml
from conftest import free_port, ray_start_lock
from test_cluster_cli import BIN, ENV, Groups

pytestmark = [pytest.mark.ray, pytest.mark.own_ray, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[1]

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


def start_head(groups: Groups) -> int:
    """A 2-CPU head on this machine, advertising the machine's own address as Ray chooses
    (no --node-ip-address); its GCS port."""
    port = free_port()
    temp = tempfile.mkdtemp(prefix="ra", dir="/tmp")
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
        port = start_head(g)
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


def farm(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
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


def test_a_process_on_one_head_asked_for_another_is_refused_in_one_line(head):
    port, advertised = head
    g = Groups()
    try:
        other = start_head(g)
        said = join(f"127.0.0.1:{port}", f"127.0.0.1:{other}")
        assert said == (f"error: address 127.0.0.1:{other}: this process is already connected to the Ray "
                        f"cluster at {advertised}")
    finally:
        g.close()


def test_exploit_and_robust_join_by_loopback_and_by_ray_address(head, tmp_path):
    port, _ = head
    r = farm("exploit", "spread_evenly", "--scenario", "outnumbered_3x3", "--seeds", "none", "--episodes", "2",
             "--exact", "never", "--address", f"127.0.0.1:{port}", "--out", str(tmp_path / "exploit"), "--quiet")
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "exploit" / "table.csv").exists()
    config = tmp_path / "robust.yaml"
    config.write_text(yaml.safe_dump({
        "name": "robust_join", "scenario": "outnumbered_3x3", "allocators": ["spread_evenly"],
        "intruders": ["drift"], "iterations": 1, "payoffs": {"episodes": 2, "seed": 2000}, "oracle": "library",
        "library": {"allocators": ["intercept"], "intruders": ["fewest_ahead"]}, "distill": None,
        "store": str(tmp_path / "capture_times.sqlite")}))
    r = farm("robust", str(config), "--out", str(tmp_path / "robust"), "--quiet",
             env={**ENV, "RAY_ADDRESS": f"127.0.0.1:{port}"})
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "robust" / "robust.json").exists()
