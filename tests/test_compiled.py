"""The compiled kernels' cache: a folder per version of their sources, the user's numba
setting left as it was, and the kernels loaded from it rather than compiled again."""

import os
import subprocess
import sys
from pathlib import Path

import workers
from workers.compiled import kernel_cache_dir

PROBE = ("import numba, workers, workers.compiled as c; "
         "print(repr(numba.config.CACHE_DIR)); print(c.kernel_cache_dir())")


def run_probe(**env):
    out = subprocess.run([sys.executable, "-c", PROBE], env={**os.environ, **env}, capture_output=True,
                         text=True, check=True, timeout=120).stdout.splitlines()
    return out[0], Path(out[1])


def test_kernels_cache_in_a_folder_named_after_their_sources():
    folder = kernel_cache_dir()
    assert folder.parent == Path(workers.__file__).parent / "__pycache__"
    assert folder.name.startswith("numba-") and len(folder.name) == len("numba-") + 16
    workers.simulate_games([[[4.0, 5.0]]], [[[8.0, 5.0]]], t_max=0.02)
    assert any(p.suffix == ".nbi" and "engine" in p.name for p in folder.rglob("*")), "the engine is not cached there"


def test_import_leaves_numba_setting_alone(tmp_path):
    setting, folder = run_probe()
    assert setting == "''"
    setting, folder = run_probe(NUMBA_CACHE_DIR=str(tmp_path))
    assert setting == repr(str(tmp_path))
    assert folder.parent == tmp_path / "swarm-farm" and folder.name == kernel_cache_dir().name


def test_a_new_process_loads_the_kernels_instead_of_compiling():
    code = ("import numpy as np; from workers import simulate_games; from workers.engine import _play; "
            "simulate_games(np.array([[[4.0, 5.0]]]), np.array([[[8.0, 5.0]]])); "
            "print(sum(_play.stats.cache_hits.values()), sum(_play.stats.cache_misses.values()))")
    workers.simulate_games([[[4.0, 5.0]]], [[[8.0, 5.0]]], t_max=0.02)  # cached by now
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300).stdout
    assert out.split() == ["1", "0"]
