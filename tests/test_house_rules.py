"""Rules of the house that hold for every file: no Python file over 500 lines, and no issue numbers
in code (an issue is a conversation that ends; the code says what it does and docs/decisions/ why)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("measure", "device", "sim", "history", "check", "batch", "service", "evaluation", "cli", "bench", "tests")
MAX_LINES = 500
ISSUE = re.compile(r"\bissues?\s*#?\d+", re.I)


def sources(suffixes=(".py",)):
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*")):
            if path.suffix in suffixes and path.is_file() and "__pycache__" not in path.parts:
                yield path


def long_files(paths, limit: int = MAX_LINES) -> list[str]:
    return [f"{p}: {n} lines" for p in paths if (n := p.read_text().count("\n")) > limit]


def issue_numbers(paths) -> list[str]:
    return [f"{p}:{i}" for p in paths if p != Path(__file__)
            for i, line in enumerate(p.read_text().splitlines(), 1) if ISSUE.search(line)]  # fmt: skip


def test_no_python_file_over_500_lines():
    assert long_files(sources()) == []


def test_no_issue_numbers_in_code():
    assert issue_numbers(sources((".py", ".js", ".toml", ".html", ".css"))) == []


def test_the_rules_find_what_they_forbid(tmp_path):
    long = tmp_path / "long.py"
    long.write_text("x = 1\n" * (MAX_LINES + 1))
    tagged = tmp_path / "tagged.py"
    tagged.write_text("# see issue #29 for the reason\n")
    fine = tmp_path / "fine.py"
    fine.write_text("# 29 issues of a magazine\n" * MAX_LINES)
    assert long_files([long, fine]) == [f"{long}: {MAX_LINES + 1} lines"]
    assert issue_numbers([tagged, fine]) == [f"{tagged}:1"]
