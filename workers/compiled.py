"""The compiled kernels' on-disk cache: kept fresh, and filled ahead of time.

numba caches each compiled function beside its source (``__pycache__/*.nbi``,
``*.nbc``) and reuses it while that one source file is unchanged; it does not
notice a change in another file whose functions were inlined into it. The
kernels here inline policies and geometry into the engine, so the cache is
keyed on all of their sources at once: `ensure_fresh_cache` (run when
the engine is imported) drops the package's numba cache files whenever any
source differs from the last stamp. `precompile` compiles every kernel once, so
that neither the test suite nor each Ray worker pays the first-call compilation
(about a minute): `make install` runs it.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["ensure_fresh_cache", "precompile"]

_ROOT = Path(__file__).resolve().parent


def _sources_digest() -> str:
    h = hashlib.sha256()
    for path in sorted([_ROOT / "engine.py", _ROOT / "geometry.py", *(_ROOT / "policies").glob("*.py")]):
        h.update(str(path.relative_to(_ROOT)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def ensure_fresh_cache() -> None:
    """Drop the package's numba cache files if any source changed since they were written."""
    digest = _sources_digest()
    stamp = _ROOT / "__pycache__" / "numba-sources.sha256"
    try:
        if stamp.read_text() == digest:
            return
    except OSError:
        pass
    try:
        for cached in _ROOT.rglob("__pycache__/*.nb[ic]"):
            cached.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        tmp = stamp.with_name(f".{stamp.name}.{os.getpid()}.tmp")
        tmp.write_text(digest)
        os.replace(tmp, stamp)
    except OSError:  # a read-only install: its files do not change under it
        pass


def precompile() -> float:
    """Compile (or load from the cache) every kernel, on tiny inputs; returns the seconds it took."""
    import time

    import numpy as np

    from workers import DEFAULT_ARENA, simulate_games, voronoi_cells
    from workers.engine import step_velocities

    t0 = time.perf_counter()
    p, e = np.array([[[4.0, 5.0]]]), np.array([[[8.0, 5.0]]])
    simulate_games(p, e, t_max=0.02, record=True)
    step_velocities(p, e, np.array([[True]]))
    voronoi_cells(np.concatenate([p, e], axis=1), np.ones((1, 2), dtype=bool), np.zeros(2, dtype=np.int64),
                  np.arange(2), DEFAULT_ARENA).area_centroid()
    return time.perf_counter() - t0

