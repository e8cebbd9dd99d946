"""Tests by speed as well as by package (docs/testing.md): the unit folders start no server process
and no browser, tests/measure imports only the core and the synthetic helpers, every test under
tests/integration, tests/studies and tests/browser carries its folder's marker, and no test skips
over an import of something the project requires."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
OWN_FOLDERS = {"integration", "studies", "browser"}
# What starts a server process or a browser: the helpers that do, and Playwright itself.
STARTERS = {"browser_helpers", "playwright", "slow_clients", "server_process.start_serve"}
# The core's tests may use the core and the synthetic helpers built on the packages below it.
MEASURE_MAY_IMPORT = {"measure", "factories", "measure_synth"}
OURS = {"measure", "device", "sim", "history", "check", "batch", "evaluation", "service", "bench", "cli"}


def imported(path: Path) -> set[str]:
    """Every module ``path`` imports, and ``module.name`` for each name taken ``from module``."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return found


def unit_files() -> list[Path]:
    return sorted(p for p in TESTS.glob("*/*.py") if p.parent.name not in OWN_FOLDERS)


def test_unit_folders_start_no_server_and_no_browser():
    wrong = {str(p.relative_to(TESTS)): sorted(m for m in imported(p) if m.split(".")[0] in STARTERS or m in STARTERS)
             for p in unit_files()}
    assert {p: m for p, m in wrong.items() if m} == {}, "move these to tests/integration or tests/browser"


def test_measure_tests_use_only_the_core():
    wrong = {}
    for path in sorted((TESTS / "measure").glob("*.py")):
        ours = {m.split(".")[0] for m in imported(path)} & (OURS | {"factories", "measure_synth"} | STARTERS)
        if ours - MEASURE_MAY_IMPORT:
            wrong[path.name] = sorted(ours - MEASURE_MAY_IMPORT)
    assert wrong == {}, "a test of the core that needs these is a study (tests/studies) or another package's test"


@pytest.mark.parametrize("folder, marker", [("integration", "integration"), ("studies", "study"), ("browser", "browser")])
def test_own_folders_carry_their_marker(request, folder, marker):
    items = [i for i in request.session.items if i.path.is_relative_to(TESTS / folder)]
    if not items:  # a run of other folders did not collect this one
        pytest.skip(f"tests/{folder} not collected in this run")
    assert [i.nodeid for i in items if i.get_closest_marker(marker) is None] == []


def test_required_modules_are_imported_not_skipped():
    """``importorskip`` would turn an import error of our own code, or of a dependency that
    pyproject.toml requires (the default and `test` extras), into a skip."""
    calls = re.compile(r"importorskip\(\s*['\"]([\w.]+)")
    found = {(p.relative_to(TESTS).as_posix(), m) for p in sorted(TESTS.rglob("*.py")) if p != Path(__file__).resolve()
             for m in calls.findall(p.read_text())}
    assert found == set()


def test_the_rules_see_what_they_forbid(tmp_path):
    bad = tmp_path / "test_x.py"
    bad.write_text("from server_process import start_serve, free_port\nimport evaluation.frames_study\n")
    assert {"server_process.start_serve", "evaluation.frames_study"} <= imported(bad)
    assert "server_process.free_port" not in STARTERS
