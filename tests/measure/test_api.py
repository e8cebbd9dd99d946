"""The measurement core's public API: one implementation per method name, and every name another
package imports from ``measure`` is exported by it."""

from __future__ import annotations

import ast
from pathlib import Path

import measure
from measure.distance import METHOD_IMPLEMENTATIONS
from measure.types import METHODS

ROOT = Path(__file__).resolve().parents[2]
# Packages that use measure as a library; bench times measure's internals against references, as tests do.
USERS = ("device", "sim", "history", "check", "batch", "evaluation", "service", "cli")


def test_every_method_name_has_one_implementation():
    assert tuple(METHOD_IMPLEMENTATIONS) == METHODS
    assert all(callable(fn) for fn in METHOD_IMPLEMENTATIONS.values())


def test_all_names_exist():
    assert sorted(measure.__all__) == sorted(set(measure.__all__))
    missing = [name for name in measure.__all__ if not hasattr(measure, name)]
    assert not missing


def imported_from_measure(path: Path) -> set[tuple[str, str, int]]:
    """(module, name, line) of every ``from measure... import name`` in ``path``."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and node.module.split(".")[0] == "measure":
            out |= {(node.module, a.name, node.lineno) for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {(a.name, "", node.lineno) for a in node.names if a.name.startswith("measure.")}
    return out


def test_other_packages_use_only_the_exported_names():
    wrong = []
    for pkg in USERS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for module, name, line in imported_from_measure(path):
                if module != "measure" and name not in measure.__all__:
                    wrong.append(f"{path.relative_to(ROOT)}:{line} imports {name or module} from {module}, which measure does not export")
    assert not wrong, "\n".join(wrong)


def test_the_check_finds_an_internal_import(tmp_path):
    bad = tmp_path / "x.py"
    bad.write_text("from measure.dline import fit_disparity_line\nimport measure.mcd\nfrom measure import Frame\n")
    assert {(m, n) for m, n, _ in imported_from_measure(bad)} == {("measure.dline", "fit_disparity_line"), ("measure.mcd", ""), ("measure", "Frame")}
