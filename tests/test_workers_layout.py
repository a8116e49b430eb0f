"""The layout of `workers/`: every file compiled into the kernels is named in their cache digest.
(Its imports: import-linter's contracts, tests/test_farm_layout.py.)"""

import ast
from pathlib import Path

import workers
from workers.compiled import _kernel_sources

ROOT = Path(workers.__file__).resolve().parent


def uses_numba(path: Path) -> bool:
    """Whether a module defines compiled code (a function decorated with, or made by, njit/jit)."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) in ("njit", "jit"):
            return True
        if isinstance(node, ast.FunctionDef) and any(
                getattr(d.func if isinstance(d, ast.Call) else d, "id", None) in ("njit", "jit")
                for d in node.decorator_list):
            return True
    return False


def test_every_compiled_file_is_in_the_kernels_cache_digest():
    compiled = {p for p in ROOT.rglob("*.py") if uses_numba(p)}
    assert {ROOT / "engine.py", ROOT / "geometry.py", ROOT / "policies" / "registry.py"} <= compiled
    assert compiled <= set(_kernel_sources())

