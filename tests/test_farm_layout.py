"""The layout of `farm/` and `workers/`, by import-linter's contracts in pyproject.toml: farm's
layers import only downward, workers never imports farm, and no package's modules import each
other in a cycle. The real tree keeps them; a copy of it with an upward import, a cycle, a module
outside every layer or a workers module importing farm breaks the contract it should."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
LINT_IMPORTS = Path(sys.executable).parent / "lint-imports"


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    """import-linter on the tree at root (its pyproject.toml, its farm/ and workers/)."""
    return subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=root, capture_output=True, text=True, timeout=120,
                          env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(root)})


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    """A copy of the project's pyproject.toml, farm/ and workers/ (the sources only)."""
    root = tmp_path_factory.mktemp("tree")
    shutil.copy(REPO / "pyproject.toml", root)
    for package in ("farm", "workers"):
        shutil.copytree(REPO / package, root / package, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def changed(tree: Path, tmp_path: Path, files: dict[str, str]) -> Path:
    """A copy of tree with text appended to each of files (paths under the copy); returns it."""
    root = tmp_path / "copy"
    shutil.copytree(tree, root)
    for rel, text in files.items():
        path = root / rel
        path.write_text((path.read_text() if path.exists() else "") + text)
    return root


def test_the_real_tree_keeps_every_contract():
    r = lint_imports(REPO)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "Contracts: 4 kept, 0 broken." in r.stdout
    assert "Analyzed" in r.stdout and " 0 dependencies" not in r.stdout  # the tree is really read


def test_the_copy_keeps_every_contract(tree):
    r = lint_imports(tree)
    assert r.returncode == 0, r.stdout[-3000:]


@pytest.mark.parametrize("where, text, broken, expected", [
    # an upward import at module level, and one in a function (it runs later; it is the same dependency)
    ("farm/core/stats.py", "\nfrom farm.alloc.envs.defenders import SwarmAllocationEnv\n", "farm imports only downward",
     "farm.core.stats -> farm.alloc.envs.defenders"),
    ("farm/games/shards.py", "\n\ndef _later():\n    from farm.studies import claims\n    return claims\n",
     "farm imports only downward", "farm.games.shards -> farm.studies.claims"),
    # inside farm.alloc: the game importing an env (in a function), one side importing the other
    ("farm/alloc/game/model.py", "\n\ndef _later():\n    from farm.alloc.envs import defenders\n    return defenders\n",
     "farm.alloc's rooms", "farm.alloc.game.model -> farm.alloc.envs.defenders"),
    ("farm/alloc/allocators/planners/minimax.py", "\n\ndef _later():\n    from farm.alloc.intruders import drift\n"
     "    return drift\n", "farm.alloc's rooms",
     "farm.alloc.allocators.planners.minimax -> farm.alloc.intruders.drift"),
    # a module outside every layer
    ("farm/extra.py", '"""A module no layer owns."""\n', "farm imports only downward", "farm.extra"),
    # workers, the data plane, importing the control plane
    ("workers/arena.py", "\n\ndef _later():\n    import farm.core.errors\n", "workers, the data plane",
     "workers.arena -> farm.core.errors"),
    # a cycle between two modules of one package, one side in a function
    ("workers/version.py", "\n\ndef _later():\n    from workers import case\n    return case\n",
     "no import cycle", "workers"),
])
def test_a_change_that_breaks_a_contract_is_found(tree, tmp_path, where, text, broken, expected):
    r = lint_imports(changed(tree, tmp_path, {where: text}))
    assert r.returncode == 1, r.stdout[-3000:]
    report = r.stdout.split("Broken contracts")[-1]
    assert broken in report and expected in report, r.stdout[-3000:]
    assert "0 broken" not in r.stdout
