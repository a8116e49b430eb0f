"""The layout of `farm/`: its modules keep to the layers of farm.layers (no upward import, no
import cycle, no module outside every layer), and the checker finds each kind of finding in
small farm/ trees built for it. (workers/'s layout: tests/test_workers_layout.py.)"""

import subprocess
import sys
from pathlib import Path

import pytest

from farm.layers import Cycle, Edge, check, format_report, layer_of

REPO = Path(__file__).resolve().parent.parent
TOTALS_CLEAN = "0 cycles, 0 upward imports, 0 unlayered modules"

# A clean farm/: a module or two on every layer, each importing downward in the ways the
# checker resolves (absolute, relative, `from a import submodule`, in a function, importlib).
CLEAN = {
    "__init__.py": '"""The face."""\n',
    "core/__init__.py": "",
    "core/errors.py": "class E(Exception):\n    pass\n",
    "runtime/__init__.py": "from farm.core.errors import E\n",
    "games/__init__.py": "",
    "games/shards.py": "from farm.core import errors\nfrom ..runtime import E\n",
    "service/__init__.py": "from farm.games.shards import *\n",
    "alloc/__init__.py": "from .env import Env\n",
    "alloc/env.py": "from farm.service import lookup\n\n\nclass Env:\n    pass\n",
    "studies/__init__.py": "",
    "studies/suite.py": "from farm.alloc import env\n",
    "experiments.py": "import farm.studies.suite\n",
    "report.py": "from farm import experiments\n",
    "cli.py": ("import importlib\n\n\ndef main(name):\n    from farm.report import r\n"
               "    importlib.import_module('farm.layers')\n    importlib.import_module(name)\n"),
    "layers.py": "",
}


def farm_tree(tmp_path: Path, changes: dict[str, str | None] | None = None) -> Path:
    """CLEAN with changes (a file's text, None removes it) written to tmp_path/farm; returns that folder."""
    files = {**CLEAN, **(changes or {})}
    for rel, text in files.items():
        if text is not None:
            (tmp_path / "farm" / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / "farm" / rel).write_text(text)
    return tmp_path / "farm"


def layers_command(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "farm.layers", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO, timeout=120)


def test_the_real_tree_keeps_its_layers():
    report = check()
    assert {"farm", "farm.cli", "farm.layers"} <= set(report.modules) and report.edges  # the tree is really read
    assert (len(report.cycles), len(report.upward), report.unlayered) == (0, 0, ()), format_report(report, quiet=True)


def test_the_command_passes_the_real_tree():
    r = layers_command()
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert TOTALS_CLEAN in r.stdout.splitlines()


def test_layer_of():
    assert [layer_of(m) for m in ("farm", "farm.core", "farm.core.stats", "farm.runtime.metrics",
                                  "farm.studies.suite.run", "farm.experiments", "farm.experiments_tune",
                                  "farm.report", "farm.layers")] == [0, 0, 0, 1, 5, 5, 5, 6, 7]
    # "farm" is the package face alone; a prefix is whole name parts
    assert [layer_of(m) for m in ("farm.config", "farm.corex", "farm.games2", "farm.cli2", "workers")] == [None] * 5


def test_a_clean_tree_has_no_finding(tmp_path):
    root = farm_tree(tmp_path)
    report = check(root)
    assert (report.cycles, report.upward, report.unlayered) == ((), (), ())
    edges = {(e.importer, e.imported, e.line, e.in_function) for e in report.edges}
    assert edges == {
        ("farm.runtime", "farm.core.errors", 1, False),
        ("farm.games.shards", "farm.core.errors", 1, False),  # from farm.core import errors: the submodule
        ("farm.games.shards", "farm.runtime", 2, False),      # from ..runtime import E: the name E of the package
        ("farm.service", "farm.games.shards", 1, False),
        ("farm.alloc", "farm.alloc.env", 1, False),
        ("farm.alloc.env", "farm.service", 1, False),         # lookup is no module of this tree
        ("farm.studies.suite", "farm.alloc.env", 1, False),
        ("farm.experiments", "farm.studies.suite", 1, False),
        ("farm.report", "farm.experiments", 1, False),
        ("farm.cli", "farm.report", 5, True),
        ("farm.cli", "farm.layers", 6, True),                 # importlib with a literal; import_module(name) unseen
    }
    assert report.modules["farm.cli"].lines == 7 and report.modules["farm.cli"].layer == 7
    r = layers_command("--root", root)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout.splitlines()
    assert out[0].split() == ["cli", "farm.cli", "7,", "farm.layers", "0"]  # the top floor first
    assert out[-2].split()[0] == "core" and out[-1] == TOTALS_CLEAN


def test_a_module_level_upward_import(tmp_path):
    report = check(farm_tree(tmp_path, {"core/stats.py": "import os\nfrom farm.alloc.env import Env\n"}))
    assert report.upward == (Edge("farm/core/stats.py", 2, "farm.core.stats", "farm.alloc.env", False),)
    assert (report.cycles, report.unlayered) == ((), ())
    text = format_report(report)
    assert "0 cycles, 1 upward imports, 0 unlayered modules" in text.splitlines()
    assert text.splitlines()[-1] == ("farm/core/stats.py:2 farm.core.stats (core) -> farm.alloc.env (alloc)"
                                     "  [module level]")


def test_an_upward_import_in_a_function(tmp_path):
    report = check(farm_tree(tmp_path, {"runtime/metrics.py": "def start():\n    import farm.games.shards as s\n"}))
    assert report.upward == (Edge("farm/runtime/metrics.py", 2, "farm.runtime.metrics", "farm.games.shards", True),)
    assert (report.cycles, report.unlayered) == ((), ())
    assert format_report(report, quiet=True).splitlines() == [
        "0 cycles, 1 upward imports, 0 unlayered modules",
        "farm/runtime/metrics.py:2 farm.runtime.metrics (runtime) -> farm.games.shards (games)  [in a function]"]


@pytest.mark.parametrize("rel, text, importer", [
    ("alloc/train.py", "from ..cli import main\n", "farm.alloc.train"),
    ("alloc/training/__init__.py", "from ...cli import main\n", "farm.alloc.training"),  # a package's own level
])
def test_a_relative_upward_import(tmp_path, rel, text, importer):
    report = check(farm_tree(tmp_path, {rel: text}))
    assert report.upward == (Edge(f"farm/{rel}", 1, importer, "farm.cli", False),)
    assert (report.cycles, report.unlayered) == ((), ())


@pytest.mark.parametrize("changes, imported", [
    ({}, "farm.alloc.env"),                                                   # env.py
    ({"alloc/env.py": None, "alloc/env/__init__.py": CLEAN["alloc/env.py"]}, "farm.alloc.env"),  # env/__init__.py
    ({"games/tasks.py": "from farm.alloc import Env\n"}, "farm.alloc"),       # a name, not a module
])
def test_from_a_package_import_a_submodule(tmp_path, changes, imported):
    report = check(farm_tree(tmp_path, {"games/tasks.py": "from farm.alloc import env\n", **changes}))
    assert report.upward == (Edge("farm/games/tasks.py", 1, "farm.games.tasks", imported, False),)
    assert (report.cycles, report.unlayered) == ((), ())


def test_a_cycle_of_function_level_imports_in_one_layer(tmp_path):
    report = check(farm_tree(tmp_path, {"alloc/a.py": "def f():\n    from farm.alloc import b\n",
                                        "alloc/b.py": "import os\n\n\ndef g():\n    from . import a\n"}))
    edges = (Edge("farm/alloc/a.py", 2, "farm.alloc.a", "farm.alloc.b", True),
             Edge("farm/alloc/b.py", 5, "farm.alloc.b", "farm.alloc.a", True))
    assert report.cycles == (Cycle(("farm.alloc.a", "farm.alloc.b"), edges),)
    assert (report.upward, report.unlayered) == ((), ())
    assert format_report(report, quiet=True).splitlines() == [
        "1 cycles, 0 upward imports, 0 unlayered modules", "cycle: farm.alloc.a, farm.alloc.b",
        "    farm.alloc.a:2 -> farm.alloc.b  [in a function]", "    farm.alloc.b:5 -> farm.alloc.a  [in a function]"]


def test_a_module_importing_itself_is_a_cycle(tmp_path):
    report = check(farm_tree(tmp_path, {"alloc/c.py": "def f():\n    import farm.alloc.c\n"}))
    edge = Edge("farm/alloc/c.py", 2, "farm.alloc.c", "farm.alloc.c", True)
    assert report.cycles == (Cycle(("farm.alloc.c",), (edge,)),)


@pytest.mark.parametrize("text, line, in_function", [
    ("import importlib\n\n\ndef load():\n    return importlib.import_module('farm.service')\n", 5, True),
    ("def load():\n    return __import__('farm.service')\n", 2, True),
    ("from importlib import import_module\n\nSERVICE = import_module('.service', package='farm')\n", 3, False),
])
def test_an_importlib_literal(tmp_path, text, line, in_function):
    report = check(farm_tree(tmp_path, {"core/loader.py": text}))
    assert report.upward == (Edge("farm/core/loader.py", line, "farm.core.loader", "farm.service", in_function),)
    assert (report.cycles, report.unlayered) == ((), ())


def test_imports_under_type_checking_try_class_and_defaults_count(tmp_path):
    text = ("from typing import TYPE_CHECKING\n"
            "if TYPE_CHECKING:\n    from farm.alloc.env import Env\n"       # 3
            "try:\n    import farm.report\nexcept ImportError:\n    pass\n"  # 5
            "class K:\n    import farm.cli\n"                                # 9
            "def f(x=__import__('farm.studies')):\n    pass\n")              # 10: a default runs at definition
    report = check(farm_tree(tmp_path, {"core/kinds.py": text}))
    assert [(e.line, e.imported, e.in_function) for e in report.upward] == [
        (3, "farm.alloc.env", False), (5, "farm.report", False), (9, "farm.cli", False), (10, "farm.studies", False)]


def test_an_unlayered_module(tmp_path):
    root = farm_tree(tmp_path, {"config.py": "from farm.core import errors\n", "gamesx.py": ""})
    report = check(root)
    assert report.unlayered == ("farm.config", "farm.gamesx")
    assert (report.cycles, report.upward) == ((), ())
    r = layers_command("--root", root, "--quiet")
    assert r.returncode == 1, r.stderr
    assert r.stdout.splitlines() == ["0 cycles, 0 upward imports, 2 unlayered modules",
                                     "farm/config.py farm.config: unlayered (no layer's prefix matches it)",
                                     "farm/gamesx.py farm.gamesx: unlayered (no layer's prefix matches it)"]
