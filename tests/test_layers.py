"""The layers import one way (ARCHITECTURE.md "Layout"): a module imports only its own package and the
layers below it, statically, inside functions or through import-by-string (a dotted module name in a
string, as ``importlib`` or a registry would take it)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# rank of each top-level package: a package may import those of a lower rank, never an equal or higher one
RANK = {"measure": 0, "device": 1, "sim": 2, "history": 3, "check": 4, "batch": 4, "evaluation": 5, "service": 5, "bench": 6, "cli": 7}
DOTTED = re.compile(r"^(%s)(\.\w+)*(:\w+)?$" % "|".join(RANK))


def imports(path: Path) -> set[tuple[str, int]]:
    """(top-level package, line) of every import of ours in ``path``, and of every dotted module name in a string."""
    tree = ast.parse(path.read_text(), str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {(a.name.split(".")[0], node.lineno) for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add((node.module.split(".")[0], node.lineno))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and DOTTED.match(node.value) and "." in node.value:
            found.add((node.value.split(".")[0], node.lineno))
    return {(pkg, line) for pkg, line in found if pkg in RANK}


def test_every_import_points_down():
    wrong = []
    for pkg, rank in RANK.items():
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for other, line in imports(path):
                if other != pkg and RANK[other] >= rank:
                    wrong.append(f"{path.relative_to(ROOT)}:{line} imports {other} (rank {RANK[other]} >= {pkg}'s {rank})")
    assert not wrong, "\n".join(wrong)


def test_no_relative_import_leaves_its_package():
    for pkg in RANK:
        for path in (ROOT / pkg).rglob("*.py"):
            depth = len(path.relative_to(ROOT).parts) - 1
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.level:
                    assert node.level < depth + (path.name != "__init__.py"), f"{path}:{node.lineno} climbs out of {pkg}"


def test_the_check_finds_an_upward_import(tmp_path):
    bad = tmp_path / "x.py"
    bad.write_text("import importlib\nimportlib.import_module('service.app')\nfrom cli.main import app\n")
    assert {p for p, _ in imports(bad)} == {"service", "cli"}
