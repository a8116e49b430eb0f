"""Importing the project changes no process-wide setting: umask, matplotlib's backend,
torch's threads, numba's cache folder; and the env without a client keeps its store in the
user's cache, never in the working directory."""

import json
import logging
import os
import subprocess
import sys

import pytest

from farm.alloc import AllocConfig, SwarmAllocationEnv

PROBE = """
import json, os, sys
import matplotlib, numba, torch
os.umask(0o027)
before = {"umask": os.umask(0o027), "backend": matplotlib.rcParams["backend"], "threads": torch.get_num_threads(),
          "numba_cache": numba.config.CACHE_DIR}
import workers, farm, farm.cli, farm.core.config, farm.core.output, farm.core.plots, farm.report, farm.runtime
import farm.games.sweep, farm.service, farm.service.table, farm.alloc, farm.alloc.training
import farm.alloc.evaluation.rollout, farm.alloc.game.plots
after = {"umask": os.umask(0o027), "backend": matplotlib.rcParams["backend"], "threads": torch.get_num_threads(),
         "numba_cache": numba.config.CACHE_DIR}
print(json.dumps({"before": before, "after": after, "pyplot": "matplotlib.pyplot" in sys.modules}))
"""


@pytest.mark.slow
def test_imports_change_no_process_setting(tmp_path):
    env = {**os.environ, "MPLBACKEND": "template"}
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300, env=env,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen["before"] == seen["after"]
    assert not seen["pyplot"]  # figures are drawn without pyplot, so no backend is ever chosen
    assert not list(tmp_path.iterdir())  # nothing written to the working directory


def test_written_files_keep_the_users_umask(tmp_path):
    """Files get mode 0666 less the caller's umask, as open() would give them."""
    from farm.core.output import atomic_write_bytes

    old = os.umask(0o027)
    try:
        atomic_write_bytes(tmp_path / "a.bin", b"x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o640
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_env_without_a_client_uses_the_users_cache_store(tmp_path, monkeypatch, caplog):
    small = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5, games=3)
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("SWARM_FARM_STORE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    with caplog.at_level(logging.INFO, logger="farm.alloc.envs.defenders"):
        env = SwarmAllocationEnv(small)
    expected = tmp_path / "cache" / "swarm-farm" / "capture_times.sqlite"
    assert env.client.backend.store.path == expected and expected.exists()
    assert f"capture-time store: {expected}" in caplog.text
    monkeypatch.setenv("SWARM_FARM_STORE", str(tmp_path / "mine.sqlite"))
    assert SwarmAllocationEnv(small).client.backend.store.path == tmp_path / "mine.sqlite"
    assert not (tmp_path / "results").exists()
