"""The layers of `farm/`, and a checker that its imports keep to them: `python -m farm.layers`.

LAYERS below, lowest first, gives each layer the module-name prefixes it owns. A module
belongs to the layer of its longest matching prefix; a prefix matches itself and its
submodules, except the package's own name `farm`, which matches only the module `farm`
(farm/__init__.py, the package face), so that every other farm module has to be placed on
purpose. A module no prefix matches is a finding (unlayered). A module may import modules of
its own layer or of a lower one; an import of a higher layer is a finding (upward), and so is
every import cycle, within one layer or not.

The algorithm, and why it is right:

- Read, never import. Each .py file under the package folder is parsed with `ast`, so the
  check runs no project code (no Ray, no torch), takes well under a second, and sees every
  import whatever order modules happen to load in. A file's module name is its path (a
  package by its folder's name); a folder without __init__.py is a namespace package.
- Every import counts: `import a.b`, `from a.b import c`, relative imports (resolved against
  the importing file's package, as Python does: `from ..core import y` in farm/alloc/env.py
  is farm.core.y or farm.core), and `importlib.import_module`/`__import__` calls with a
  literal name; at module level, in class bodies, under `if TYPE_CHECKING:` or try/except,
  and in functions. A function-level import runs when the function is called: it is the
  same dependency, only later, so it may not point upward either, and it closes a cycle just
  the same (hiding a cycle in a function is how one usually survives). Each import is one
  edge (importer, imported, line, in a function or not); only imports of farm modules are
  kept. `from a.b import c` imports the module a.b.c when that is a module of the tree,
  otherwise the name c of a.b. A name computed at run time is invisible here (the service's
  actor imports the module an error message names); the layering of such code is the
  reviewer's.
- An import is of the module it names. Python also runs the parents' __init__.py, but a
  module's parent is on the module's own layer or is `farm` (the lowest), so counting them
  would add no upward import; and it would make every package __init__ that imports its
  submodules a cycle with them, which Python handles (a submodule importing a sibling while
  its package initialises). The cycle that does break, a submodule taking a name from its
  package's __init__ while the __init__ imports it, is written as an import of the package
  and so is found.
- Cycles are the strongly connected components of the module graph (Tarjan's algorithm,
  iterative): every cycle lies inside one component, and in a component of two or more
  modules every module reaches every other and back, so listing the components (and the
  modules importing themselves) lists every cycle, each once, with every edge that ties it,
  without enumerating the possibly exponential number of elementary cycles.
- An imported farm module missing from the tree (mid-refactor) is layered by its name like
  any other; it has no imports of its own, so it closes no cycle.

`check(root)` returns a Report; `format_report(report)` is what the command prints; the exit
status is 0 without findings, 1 with, 2 for a root that is not a folder or a file that does
not parse. Tested: tests/test_farm_layout.py.
"""

from __future__ import annotations

import argparse
import ast
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

__all__ = ["PACKAGE", "LAYERS", "Module", "Edge", "Cycle", "Report", "layer_of", "module_files", "imports_of",
           "strong_components", "check", "format_report", "main"]

PACKAGE = "farm"

# The layers, lowest first: (name, module-name prefixes it owns).
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("core", ("farm", "farm.core")),      # the package face; errors, output, progress, plots, config loading, stats
    ("runtime", ("farm.runtime",)),       # starting/joining Ray, bounded submission, metrics
    ("games", ("farm.games",)),           # shards, sizes, the Ray tasks that play shards, pe_table, sweeps
    ("service", ("farm.service",)),       # the capture-time service
    ("alloc", ("farm.alloc",)),           # allocation: config, model, env, scenarios, policies, rollout, training
    ("studies", ("farm.studies", "farm.experiments", "farm.experiments_tune")),  # suite, experiments, claims
    ("report", ("farm.report",)),
    ("cli", ("farm.cli", "farm.layers")),
)

_FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)
_DYNAMIC = ("import_module", "__import__")  # importlib.import_module(name), import_module(name), __import__(name)


@dataclass(frozen=True)
class Module:
    """A module of the tree: name (dotted), path (its file), lines (the file's line count) and
    layer (an index into LAYERS, None when unlayered)."""

    name: str
    path: Path
    lines: int
    layer: int | None


@dataclass(frozen=True, order=True)
class Edge:
    """One import of a farm module: file (the importer's file, 'farm/alloc/env.py'), line, importer
    and imported (dotted module names), in_function (the import runs when a function is called)."""

    file: str
    line: int
    importer: str
    imported: str
    in_function: bool


@dataclass(frozen=True)
class Cycle:
    """An import cycle: modules (a strongly connected component of the module graph, sorted; one
    module for a module importing itself) and edges (every import between them)."""

    modules: tuple[str, ...]
    edges: tuple[Edge, ...]


@dataclass(frozen=True)
class Report:
    """What check() found in the tree at root of the package (its name) with its layers: modules
    (by name), edges (every import of the package's modules, sorted by file and line), and the
    findings: cycles, upward (edges to a higher layer) and unlayered (module names)."""

    root: Path
    package: str
    layers: tuple
    modules: dict[str, Module]
    edges: tuple[Edge, ...]
    cycles: tuple[Cycle, ...]
    upward: tuple[Edge, ...]
    unlayered: tuple[str, ...]

    @property
    def findings(self) -> int:
        """The number of findings (0: the tree keeps to its layers)."""
        return len(self.cycles) + len(self.upward) + len(self.unlayered)


def layer_of(module: str, layers=LAYERS, package: str = PACKAGE) -> int | None:
    """The index into layers of the layer owning a module (its longest matching prefix), or None.
    The package's own name (`farm`) matches only the package itself; any other prefix also
    matches its submodules."""
    best, best_length = None, -1
    for index, (_, prefixes) in enumerate(layers):
        for prefix in prefixes:
            matches = module == prefix or (prefix != package and module.startswith(prefix + "."))
            if matches and len(prefix) > best_length:
                best, best_length = index, len(prefix)
    return best


def module_files(root: Path, package: str = PACKAGE) -> dict[str, Path]:
    """Every module of the package folder root, by dotted name (a package by its own name)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = [package, *path.relative_to(root).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _namespaces(root: Path, modules: dict[str, Path], package: str) -> set[str]:
    """The names of the package folders of the tree, __init__.py or not (every folder above a module)."""
    names = set()
    for path in modules.values():
        for folder in path.relative_to(root).parents:
            names.add(".".join([package, *folder.parts]))
    return names


def _relative_base(importer: str, is_package: bool, level: int, module: str | None) -> str | None:
    """The absolute name `from <level dots><module> import ...` means in importer, None when the
    dots climb above the top package (an error Python would raise)."""
    here = importer.split(".") if is_package else importer.split(".")[:-1]
    if level - 1 >= len(here):
        return None
    here = here[: len(here) - (level - 1)]
    return ".".join([*here, module] if module else here)


def _dynamic_target(call: ast.Call) -> str | None:
    """The module an importlib.import_module / __import__ call with a literal name imports, or None."""
    func = call.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if name not in _DYNAMIC or not call.args:
        return None
    first = call.args[0]
    if not (isinstance(first, ast.Constant) and isinstance(first.value, str)):
        return None
    target = first.value
    if target.startswith(".") and name == "import_module":  # import_module(".x", package="farm.alloc")
        package = next((k.value for k in call.keywords if k.arg == "package"), None)
        if len(call.args) > 1:
            package = call.args[1]
        if not (isinstance(package, ast.Constant) and isinstance(package.value, str)):
            return None
        level = len(target) - len(target.lstrip("."))
        return _relative_base(package.value, True, level, target.lstrip(".") or None)
    return target


def _targets(node: ast.AST, importer: str, is_package: bool, known: set[str]) -> list[str]:
    """The modules one node imports (an import statement or a dynamic import call), any package's."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        base = node.module or ""
        if node.level:
            base = _relative_base(importer, is_package, node.level, node.module)
            if base is None:
                return []
        return [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
    if isinstance(node, ast.Call):
        target = _dynamic_target(node)
        return [target] if target else []
    return []


def _walk(node: ast.AST, in_function: bool = False):
    """Every node below node, with whether it runs inside a function: a function's (or lambda's)
    body does; its decorators and default values run where the function is defined."""
    for field, value in ast.iter_fields(node):
        inner = in_function or (field == "body" and isinstance(node, _FUNCTIONS))
        for child in value if isinstance(value, list) else [value]:
            if isinstance(child, ast.AST):
                yield child, inner
                yield from _walk(child, inner)


def imports_of(name: str, path: Path, file: str, known: set[str], package: str = PACKAGE) -> list[Edge]:
    """Every import of a module of the package in one module's source, sorted, one edge per (line,
    imported). name: the module's dotted name; path: its file; file: the file as printed; known:
    the tree's module and package names (for `from a import b`, b a module or a name)."""
    tree = ast.parse(path.read_text(), str(path))
    is_package = path.name == "__init__.py"
    edges = set()
    for node, in_function in _walk(tree):
        for target in _targets(node, name, is_package, known):
            if target == package or target.startswith(package + "."):
                edges.add(Edge(file, node.lineno, name, target, in_function))
    return sorted(edges)


def strong_components(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of a directed graph (node -> successors), each sorted,
    in order of their first node (Tarjan's algorithm, without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            for nxt in successors:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    components.append(sorted(component))
    return sorted(components)


def _cycles(edges: tuple[Edge, ...]) -> tuple[Cycle, ...]:
    """The import cycles of the edges: components of two or more modules, and self-imports."""
    graph: dict[str, set[str]] = {}
    for edge in edges:
        graph.setdefault(edge.importer, set()).add(edge.imported)
    cycles = []
    for component in strong_components(graph):
        members = set(component)
        tie = tuple(e for e in edges if e.importer in members and e.imported in members)
        if len(component) > 1 or tie:
            cycles.append(Cycle(tuple(component), tie))
    return tuple(cycles)


def check(root: Path | None = None, package: str = PACKAGE, layers=LAYERS) -> Report:
    """Check the package folder root (default: farm's, the one holding this file), whose package
    is named package, against layers (default: farm's LAYERS). Raises SyntaxError for a file
    that does not parse. tests/test_workers_layout.py checks workers/ with it too."""
    root = Path(__file__).resolve().parent if root is None else Path(root)
    files = module_files(root, package)
    known = set(files) | _namespaces(root, files, package)
    modules, edges = {}, []
    for name, path in files.items():
        file = "/".join([package, *path.relative_to(root).parts])
        edges.extend(imports_of(name, path, file, known, package))
        modules[name] = Module(name, path, len(path.read_text().splitlines()), layer_of(name, layers, package))
    edges = tuple(sorted(edges))
    upward = tuple(e for e in edges if (i := layer_of(e.importer, layers, package)) is not None
                   and (j := layer_of(e.imported, layers, package)) is not None and j > i)
    unlayered = tuple(name for name, module in modules.items() if module.layer is None)
    return Report(root, package, tuple(layers), modules, edges, _cycles(edges), upward, unlayered)


def _layer_name(report: Report, module: str) -> str:
    layer = layer_of(module, report.layers, report.package)
    return "unlayered" if layer is None else report.layers[layer][0]


def _where(edge: Edge) -> str:
    return "[in a function]" if edge.in_function else "[module level]"


def format_report(report: Report, quiet: bool = False) -> str:
    """The command's output: the layers from the top floor down, each with its modules and their
    line counts (not when quiet), the totals line, then each finding, one a line."""
    lines = []
    if not quiet:
        floors = [(name, index) for index, (name, _) in reversed(list(enumerate(report.layers)))]
        if report.unlayered:
            floors.append(("unlayered", None))
        for name, index in floors:
            members = [f"{m.name} {m.lines}" for _, m in sorted(report.modules.items()) if m.layer == index]
            lines.append(textwrap.fill(", ".join(members) or "(none)", width=100, initial_indent=f"{name:<10} ",
                                       subsequent_indent=" " * 11, break_on_hyphens=False))
    lines.append(f"{len(report.cycles)} cycles, {len(report.upward)} upward imports, "
                 f"{len(report.unlayered)} unlayered modules")
    for cycle in report.cycles:
        lines.append(textwrap.fill(", ".join(cycle.modules), width=100, initial_indent="cycle: ",
                                   subsequent_indent=" " * 7, break_on_hyphens=False))
        lines.extend(f"    {e.importer}:{e.line} -> {e.imported}  {_where(e)}" for e in cycle.edges)
    for e in report.upward:
        lines.append(f"{e.file}:{e.line} {e.importer} ({_layer_name(report, e.importer)}) -> "
                     f"{e.imported} ({_layer_name(report, e.imported)})  {_where(e)}")
    for name in report.unlayered:
        file = "/".join([report.package, *report.modules[name].path.relative_to(report.root).parts])
        lines.append(f"{file} {name}: unlayered (no layer's prefix matches it)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the checker: prints format_report's text; returns 0 without findings, 1 with, 2 for a
    --root that is not a folder or a file that does not parse (one line on stderr)."""
    parser = argparse.ArgumentParser(prog="python -m farm.layers", description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=None, help="the farm package folder to check "
                        "(default: the one holding farm/layers.py)")
    parser.add_argument("--quiet", action="store_true", help="print only the totals line and the findings")
    args = parser.parse_args(argv)
    if args.root is not None and not args.root.is_dir():
        print(f"farm.layers: error: --root: not a folder: {args.root}", file=sys.stderr)
        return 2
    try:
        report = check(args.root)
    except SyntaxError as e:
        print(f"farm.layers: error: {e.filename}:{e.lineno}: {e.msg}", file=sys.stderr)
        return 2
    print(format_report(report, quiet=args.quiet))
    return 1 if report.findings else 0


if __name__ == "__main__":
    sys.exit(main())
