"""The committed reports under docs/eval are what their generators write from results.json: a figure
edited by hand in a report.md, or a generator changed without re-rendering, fails here."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from evaluation.render import kind, main, render

EVAL = Path(__file__).resolve().parents[2] / "docs" / "eval"
FOLDERS = sorted(p.parent for p in EVAL.glob("*/results.json"))


def test_every_study_has_a_committed_report():
    import json

    kinds = {kind(json.loads((f / "results.json").read_text())) for f in FOLDERS}
    assert kinds == {"sim", "middlebury", "stress-middlebury", "stress-sim", "stress", "frames", "shapes"}


@pytest.mark.parametrize("folder", FOLDERS, ids=[f.name for f in FOLDERS])
def test_report_is_its_generators_output(folder):
    assert (folder / "report.md").read_text() == render(folder), f"python -m evaluation.render docs/eval re-renders {folder.name}"


def test_check_finds_a_hand_edit(tmp_path, capsys):
    copy = tmp_path / "sim"
    shutil.copytree(EVAL / "sim", copy, ignore=shutil.ignore_patterns("*.png", "*.csv"))
    assert main([str(tmp_path), "--check"]) == 0
    report = copy / "report.md"
    report.write_text(report.read_text().replace("| basic (window median) | **", "| basic (window median) | **1", 1))
    assert main([str(tmp_path), "--check"]) == 1
    assert main([str(tmp_path)]) == 0 and main([str(tmp_path), "--check"]) == 0  # re-rendered
