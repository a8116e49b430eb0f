"""The layout of `workers/`: no import cycle between its modules (module-level and
function-level imports alike), and every file compiled into the kernels named in their
cache digest. (Docstrings: tests/test_docstrings.py.)"""

import ast
from pathlib import Path

import pytest

import workers
from farm.layers import check, module_files, strong_components
from workers.compiled import _kernel_sources
from workers.policies.registry import EVADERS, PURSUERS

ROOT = Path(workers.__file__).resolve().parent


def import_graph(folder: Path, package: str) -> dict[str, set[str]]:
    """module -> the package's modules it imports anywhere in its code (at the top or in a
    function), read from the source by farm.layers (the farm/ checker's reader, run on another
    package): `import a.b`, `from a.b import c` (c itself when it is a module), relative imports."""
    report = check(folder, package=package, layers=())
    graph = {name: set() for name in report.modules}
    for edge in report.edges:
        target = edge.imported
        while target and target not in graph:  # `import a.b.c` where c is not a module
            target = target.rpartition(".")[0]
        if target and target != edge.importer:
            graph[edge.importer].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> set[str] | None:
    """The modules of one import cycle of the graph (a strongly connected component of two or
    more), or None when it has none."""
    return next((set(c) for c in strong_components(graph) if len(c) > 1), None)


def workers_graph() -> dict[str, set[str]]:
    graph = import_graph(ROOT, "workers")
    # The registry imports the policy modules by name (importlib), which the source does not show.
    graph["workers.policies.registry"] |= {f"workers.policies.{name}" for name in (*PURSUERS, *EVADERS)}
    return graph


def test_workers_has_no_import_cycle():
    graph = workers_graph()
    assert find_cycle(graph) is None
    # the graph is really read: the edges the layout is about are there
    assert {"workers.version", "workers.policies"} <= graph["workers.case"]
    assert {"workers.version", "workers.case"} <= graph["workers.engine"]
    assert {"workers.case", "workers.stats", "workers.engine"} <= graph["workers.montecarlo"]
    assert "workers.engine" in graph["workers.compiled"]  # a function-level import
    assert "workers.engine" not in graph["workers.case"] | graph["workers.stats"]


def write_package(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root / "pkg"


@pytest.mark.parametrize("y_imports_x", [
    "from pkg import x\n",                      # the submodule, named through its package
    "def f():\n    from pkg.x import g\n",     # in a function
    "def f():\n    from .x import g\n",        # relative, in a function
    "import pkg.x\n",
])
def test_the_checker_finds_a_built_cycle(tmp_path, y_imports_x):
    pkg = write_package(tmp_path, {"pkg/__init__.py": "", "pkg/x.py": "from pkg.y import f\n\ndef g():\n    pass\n",
                                   "pkg/y.py": y_imports_x, "pkg/z.py": "from pkg import y\n"})
    assert find_cycle(import_graph(pkg, "pkg")) == {"pkg.x", "pkg.y"}


def test_the_checker_passes_a_package_without_a_cycle(tmp_path):
    pkg = write_package(tmp_path, {"pkg/__init__.py": "from pkg.x import g\nfrom pkg.y import f\n",
                                   "pkg/x.py": "from pkg.y import f\n\ndef g():\n    from pkg import z\n",
                                   "pkg/y.py": "import os\n\ndef f():\n    pass\n",
                                   "pkg/z.py": "from . import y\n"})
    graph = import_graph(pkg, "pkg")
    assert graph["pkg.x"] == {"pkg.y", "pkg.z"} and graph["pkg.z"] == {"pkg.y"}
    assert find_cycle(graph) is None
    graph["pkg.y"].add("pkg")  # the package's __init__ imports x, which imports y
    assert find_cycle(graph) == {"pkg", "pkg.x", "pkg.y", "pkg.z"}  # x imports z, which imports y too


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
    compiled = {p for p in module_files(ROOT, "workers").values() if uses_numba(p)}
    assert {ROOT / "engine.py", ROOT / "geometry.py", ROOT / "policies" / "registry.py"} <= compiled
    assert compiled <= set(_kernel_sources())

