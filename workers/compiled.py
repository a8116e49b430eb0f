"""Where the compiled kernels are cached on disk, and filling that cache ahead of time.

numba caches each compiled function (``cache=True``) and reuses it while the one source file
that defines it is unchanged; it does not notice a change in another file whose functions were
inlined into it, and the engine inlines the policies and the geometry. So the kernels' cache
folder is named after a hash of all their sources: any change to any of them starts a fresh
folder, and a folder is never read by code other than the code that wrote it (no deletion, so
no race between processes). The folder is ``numba-<hash>`` under the package's ``__pycache__``
when that is writable (shared by every process of a checkout: the test suite, each Ray worker),
else under ``$NUMBA_CACHE_DIR`` or the user cache (``~/.cache/swarm-farm``). `kernel_cache`
points numba there only while the package's kernels are being defined (numba reads the setting
then), and puts the user's setting back after.

`precompile` compiles every kernel once, so that neither the test suite nor each Ray worker
pays the first call: `make install` runs it.
"""

from __future__ import annotations

import hashlib
import os
from contextlib import contextmanager
from pathlib import Path

__all__ = ["kernel_cache", "kernel_cache_dir", "precompile"]

_ROOT = Path(__file__).resolve().parent


def _kernel_sources() -> list[Path]:
    """Every file whose code is compiled into the kernels: the engine, the geometry, and the
    policies with their registry (which generates the dispatch the engine inlines)."""
    return sorted([_ROOT / "engine.py", _ROOT / "geometry.py", *(_ROOT / "policies").glob("*.py")])


def _sources_digest() -> str:
    h = hashlib.sha256()
    for path in _kernel_sources():
        h.update(str(path.relative_to(_ROOT)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".probe-{os.getpid()}"
        probe.touch()
        probe.unlink()
        return True
    except OSError:
        return False


def kernel_cache_dir() -> Path:
    """The cache folder of this version of the kernels' sources (see the module doc)."""
    name = f"numba-{_sources_digest()}"
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "swarm-farm" / name
    in_tree = _ROOT / "__pycache__"
    if _writable(in_tree):
        return in_tree / name
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "swarm-farm" / name


@contextmanager
def kernel_cache():
    """numba's cache folder set to kernel_cache_dir() for the functions defined inside."""
    from numba import config

    before = config.CACHE_DIR
    config.CACHE_DIR = str(kernel_cache_dir())
    try:
        yield
    finally:
        config.CACHE_DIR = before


def precompile() -> float:
    """Compile (or load from the cache) every kernel, on tiny inputs; returns the seconds it took."""
    import time

    import numpy as np

    # Here, not at the top: this module is imported before the kernels are defined (in kernel_cache()).
    from workers.arena import DEFAULT_ARENA
    from workers.engine import simulate_games, step_velocities
    from workers.geometry import voronoi_cells

    t0 = time.perf_counter()
    p, e = np.array([[[4.0, 5.0]]]), np.array([[[8.0, 5.0]]])
    simulate_games(p, e, t_max=0.02, record=True)
    step_velocities(p, e, np.array([[True]]))
    voronoi_cells(np.concatenate([p, e], axis=1), np.ones((1, 2), dtype=bool), np.zeros(2, dtype=np.int64),
                  np.arange(2), DEFAULT_ARENA).area_centroid()
    return time.perf_counter() - t0
