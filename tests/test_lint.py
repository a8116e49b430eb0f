"""ruff's rules in pyproject.toml (`make lint`): the tree keeps them, and they find what they
should. pydocstyle's D1 rules give every public module, class, function and method of farm/ and
workers/ a docstring (docs/style.md); tests/, benchmarks/ and tools/ are left out of the D rules.

pydocstyle counts a name public when it has no leading underscore and, in a module with an
`__all__`, is listed there; docs/style.md counts every name without a leading underscore. So the
D1 rules are also run on a copy of farm/ and workers/ with every `__all__` set aside."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
RUFF = Path(sys.executable).parent / "ruff"
DOCSTRING_RULES = "D100,D101,D102,D103,D104,D106"  # pydocstyle's D1 but D105 and D107, which pyproject.toml ignores


def ruff(root: Path, *args) -> subprocess.CompletedProcess:
    """ruff check at root with root's pyproject.toml, in its concise one-line-a-finding output."""
    return subprocess.run([str(RUFF), "check", "--no-cache", "--output-format", "concise", *map(str, args)], cwd=root,
                          capture_output=True, text=True, timeout=300)


def findings(r: subprocess.CompletedProcess) -> set[tuple[str, str]]:
    """(path, rule) of each finding in ruff's concise output."""
    out = set()
    for line in r.stdout.splitlines():
        parts = line.split(":")
        if len(parts) >= 4 and parts[1].isdigit():
            out.add((parts[0], parts[3].split()[0]))
    return out


def without_all(path: Path) -> None:
    """path's module-level `__all__ = [...]` made blank lines (the other lines keep their numbers)."""
    lines = path.read_text().splitlines(keepends=True)
    for node in ast.parse("".join(lines)).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            for i in range(node.lineno - 1, node.end_lineno):
                lines[i] = "\n"
    path.write_text("".join(lines))


def test_the_tree_is_clean():
    r = ruff(REPO, ".")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]


def test_every_public_definition_has_a_docstring_whatever_its_modules_all(tmp_path):
    shutil.copy(REPO / "pyproject.toml", tmp_path)
    for package in ("farm", "workers"):
        shutil.copytree(REPO / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    for path in tmp_path.rglob("*.py"):
        without_all(path)
    r = ruff(tmp_path, "--select", DOCSTRING_RULES, "farm", "workers")
    assert r.returncode == 0, "no docstring:\n" + r.stdout[-3000:] + r.stderr[-2000:]


UNDOCUMENTED = '''\
def shown():
    pass


def _hidden():
    pass


class K:
    """K."""

    def method(self):
        pass

    def _private(self):
        pass
'''


def test_the_rules_find_a_missing_docstring_in_farm_and_workers_only(tmp_path):
    """A module, a function and a method without a docstring are found in farm/ and workers/,
    not in tests/; private names are not asked for one."""
    shutil.copy(REPO / "pyproject.toml", tmp_path)
    for folder in ("farm", "workers", "tests"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "m.py").write_text(UNDOCUMENTED)
    r = ruff(tmp_path, ".")
    assert r.returncode == 1
    assert findings(r) == {(f"{folder}/m.py", rule) for folder in ("farm", "workers")
                           for rule in ("D100", "D103", "D102")}, r.stdout
    # shown and K.method, not _hidden or K._private
    assert r.stdout.count("D103") == r.stdout.count("D102") == 2, r.stdout


def test_a_name_left_out_of_all_is_found_once_all_is_set_aside(tmp_path):
    shutil.copy(REPO / "pyproject.toml", tmp_path)
    (tmp_path / "farm").mkdir()
    module = tmp_path / "farm" / "m.py"
    module.write_text('"""M."""\n\n__all__ = ["listed"]\n\n\ndef listed():\n    pass\n\n\ndef unlisted():\n    pass\n')
    assert findings(ruff(tmp_path, "farm")) == {("farm/m.py", "D103")}  # listed only: pydocstyle's public
    without_all(module)
    r = ruff(tmp_path, "--select", DOCSTRING_RULES, "farm")
    assert [line.split(": ")[0] for line in r.stdout.splitlines() if ": D103 " in line] == ["farm/m.py:6:5",
                                                                                          "farm/m.py:10:5"], r.stdout
