"""The layout of `workers/`: no import cycle between its modules (module-level and
function-level imports alike), and every file compiled into the kernels named in their
cache digest. (Docstrings: tests/test_docstrings.py.)"""

import ast
from pathlib import Path

import pytest

import workers
from workers.compiled import _kernel_sources
from workers.policies.registry import EVADERS, PURSUERS

ROOT = Path(workers.__file__).resolve().parent


def module_files(folder: Path, package: str) -> dict[str, Path]:
    """Every module of the package in folder, by dotted name (a package by its own name)."""
    out = {}
    for path in sorted(folder.rglob("*.py")):
        parts = [package, *path.relative_to(folder).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def import_graph(folder: Path, package: str) -> dict[str, set[str]]:
    """module -> the package's modules it imports anywhere in its code (at the top or in a
    function), read from the source: `import a.b`, `from a.b import c` (c itself when it is
    a module), relative imports too."""
    modules = module_files(folder, package)
    graph = {name: set() for name in modules}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    here = name.split(".") if is_package else name.split(".")[:-1]
                    here = here[: len(here) - (node.level - 1)]
                    base = ".".join([*here, base] if base else here)
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                           for alias in node.names]
            for target in targets:
                while target and target not in modules:  # `import a.b.c` where c is not a module
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph[name].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of the graph as [a, b, ..., a], or None when it has none."""
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


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
    cycle = find_cycle(import_graph(pkg, "pkg"))
    assert cycle is not None and cycle[0] == cycle[-1] and set(cycle) == {"pkg.x", "pkg.y"}


def test_the_checker_passes_a_package_without_a_cycle(tmp_path):
    pkg = write_package(tmp_path, {"pkg/__init__.py": "from pkg.x import g\nfrom pkg.y import f\n",
                                   "pkg/x.py": "from pkg.y import f\n\ndef g():\n    from pkg import z\n",
                                   "pkg/y.py": "import os\n\ndef f():\n    pass\n",
                                   "pkg/z.py": "from . import y\n"})
    graph = import_graph(pkg, "pkg")
    assert graph["pkg.x"] == {"pkg.y", "pkg.z"} and graph["pkg.z"] == {"pkg.y"}
    assert find_cycle(graph) is None
    graph["pkg.y"].add("pkg")  # the package's __init__ imports x, which imports y
    assert find_cycle(graph) == ["pkg", "pkg.x", "pkg.y", "pkg"]


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

