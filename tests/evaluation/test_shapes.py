"""The shapes study (evaluation/shapes.py): its summary counts what it says on hand-made records, a
reduced run on the simulator holds the verdict-honesty and area targets for two seed bases, and
`depthruler eval shapes` writes its table, CSV and plots."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.eval import app
from evaluation.shapes import DIMS, ShapeJob, checks, plan, run, summarize
from evaluation.shapes_report import write_shapes_report


def _box(range_m, errs, quality="good", full=True, sigma_pct=1.0, profile="stress"):
    rec = {"kind": "box", "profile": profile, "range_m": range_m, "full_view": full, "quality": quality, "hgt_err_pct": errs[2]}
    for d, e in zip(DIMS, errs):
        rec |= {f"true_{d}_m": 1.0, f"{d}_m": 1.0 + e / 100, f"{d}_sigma_m": sigma_pct / 100, f"{d}_err_pct": e}
    rec |= {"hgt_m": 1.0 + errs[2] / 100, "hgt_sigma_m": sigma_pct / 100, "box_ms": 10.0}
    return rec


def test_summary_counts_what_it_says():
    recs = [_box(1.0, (1.0, -1.5, 0.5)), _box(1.5, (3.0, 1.0, -0.5)), _box(1.8, (-6.0, 0.0, 0.1)),
            _box(2.5, (2.0, 2.0, 2.0), quality="check"), _box(2.2, (math.nan,) * 3, quality="refused"),
            _box(1.0, (20.0, 0.0, 0.0), quality="check", full=False), _box(1.0, (9.0, 0.0, 0.0), quality="good", full=False),
            {"kind": "panel", "profile": "stress", "range_m": 1.0, "true_area_m2": 1.0, "area_m2": 1.01, "area_sigma_m2": 0.01,
             "area_err_pct": 1.0}]
    s = summarize(recs)["stress"]
    near = s["bands"]["0.6-2 m"]
    assert near["n"] == 3 and near["length"] == pytest.approx(3.0) and near["width"] == pytest.approx(1.0)
    assert s["bands"]["2-3 m"] == {"n": 2, "refused": 1, "length": 2.0, "width": 2.0, "height": 2.0}
    assert s["good"] == 3 and s["good_above_5pct"] == 1 and s["good_above_5pct_share"] == pytest.approx(1 / 5)
    # 9 good dimensions at 1 % sigma: |err| <= 2 % for 1, 1.5, 0.5, 1, 0.5, 0, 0.1 -> 7 of 9 (3 % and 6 % are not).
    assert s["coverage_dims"] == 9 and s["coverage_2sigma"] == pytest.approx(7 / 9)
    assert s["cut_or_occluded"] == {"n": 2, "good": 1, "check": 1, "unreliable": 0, "refused": 0, "not_good_share": 0.5}
    # Fully seen at 1-3 m: 1.0, 1.5, 1.8, 2.5 and the refused 2.2 m.
    assert s["height"]["n"] == 5 and s["height"]["refused"] == 1 and s["height"]["median_abs_err_pct"] == pytest.approx(0.5)
    assert s["area"]["median_abs_err_pct"] == pytest.approx(1.0) and s["area"]["coverage_2sigma"] == 1.0
    met = {name: ok for _, name, _, _, ok in checks({"stress": s})}
    assert met["panel area median abs. error (%)"] and not met["cut/occluded boxes not good (share)"]
    assert not met["box length median abs. error 0.6-2 m (%)"] and met["box width median abs. error 0.6-2 m (%)"]


def test_plan_draws_each_profile_from_the_same_seeds():
    jobs = plan(3, 2, seed=10, profiles=("stress", "paper"), width=640, height=360)
    assert len(jobs) == 10
    assert [j.seed for j in jobs if j.profile == "paper" and j.kind == "box"] == [10, 11, 12]
    assert jobs[0] == ShapeJob("box", 10, "stress", 640, 360)


@pytest.mark.slow  # a study of 11 rendered shapes per seed: the full suite's, not the fast loop's
@pytest.mark.parametrize("base", [0, 50])
def test_reduced_study_holds_the_honesty_and_area_targets(base, tmp_path):
    records = run(plan(8, 3, base, ("stress",), 640, 360), workers=1)
    s = summarize(records)["stress"]
    assert s["full_view"] >= 4
    # Verdict honesty: no "good" box answer off by more than 5 %, cut or hidden boxes never "good".
    assert s["good_above_5pct"] == 0
    assert s["cut_or_occluded"]["good"] == 0
    assert s["area"]["median_abs_err_pct"] <= 2.0
    # Heights above the plane found under the click, at 640 px (the 1 % target is for 1280 px: docs/eval/shapes).
    assert s["height"]["median_abs_err_pct"] <= 2.0
    paths = write_shapes_report(tmp_path, records, {"boxes": 8, "panels": 3, "seed": base, "width": 640, "height": 360, "wall_time_s": 1.0})
    rows = list(csv.DictReader(paths["csv"].open()))
    assert len(rows) == len(records) == 11
    assert json.loads(paths["results"].read_text())["kind"] == "shapes"
    assert "## Targets" in paths["report"].read_text()
    assert paths["box_errors"].stat().st_size > 1000 and paths["box_verdicts"].stat().st_size > 1000
    errs = np.array([float(r["height_err_pct"]) for r in rows if r["kind"] == "box" and r["quality"] != "refused"])
    assert errs.size and np.all(np.isfinite(errs))


def test_eval_shapes_command(tmp_path):
    res = CliRunner().invoke(app, ["shapes", "--out", str(tmp_path / "out"), "--boxes", "2", "--panels", "1", "--profile", "stress",
                                   "--width", "480", "--height", "270", "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert "stress: panel area median abs. error" in res.output
    assert {p.name for p in (tmp_path / "out").iterdir()} == {"report.md", "results.json", "shapes.csv", "box_errors.png", "box_verdicts.png"}
    bad = CliRunner().invoke(app, ["shapes", "--out", str(tmp_path / "x"), "--profile", "tablet"])
    assert bad.exit_code == 2 and "tablet" in bad.output
