"""Every public module, class, function and method of farm/ and workers/ has a docstring
(docs/style.md)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _public_without_docstring(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    missing = [] if ast.get_docstring(tree) else ["<module>"]

    def visit(node, prefix=""):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = child.name
                if name.startswith("_"):
                    continue
                if ast.get_docstring(child) is None:
                    missing.append(prefix + name)
                if isinstance(child, ast.ClassDef):
                    visit(child, prefix + name + ".")

    visit(tree)
    return missing


def test_every_public_definition_has_a_docstring():
    missing = [f"{p.relative_to(ROOT)}: {name}" for package in ("farm", "workers")
               for p in sorted((ROOT / package).rglob("*.py")) for name in _public_without_docstring(p)]
    assert not missing, "no docstring:\n" + "\n".join(missing)


def test_the_checker_finds_a_missing_docstring(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""A module."""\n\ndef shown():\n    pass\n\n\ndef _hidden():\n    pass\n\n\n'
                 'class K:\n    """K."""\n\n    def method(self):\n        pass\n')
    assert _public_without_docstring(f) == ["shown", "K.method"]
