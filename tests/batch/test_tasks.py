"""Task tables row by row: every bad row is an error row naming its field while the others are
measured, on every executor; a CSV saved by Excel (UTF-8 with a byte-order mark) reads."""

from __future__ import annotations

import csv
import json
import math

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from batch.executors import InProcessExecutor, PoolExecutor
from batch.run import close_readers, run_batch
from batch.tasks import MAX_FRAME, read_tasks
from batch_tables import HEADER, invoke, stable, truth
from cli.main import app as cli
from device.formats.recording import open_recording
from measure import MeasureOptions, measure_distance


def _bad_rows(rec: str, p1, p2) -> list[tuple[list, str]]:
    """(row, the field its error names) for every kind of bad cell, each beside valid ones."""
    (x1, y1), (x2, y2) = p1, p2
    return [
        ([rec, 2**63, x1, y1, x2, y2, "", "frame 2^63"], "frame"),
        ([rec, MAX_FRAME + 2, x1, y1, x2, y2, "", "frame 2^53 + 1"], "frame"),
        ([rec, "1e300", x1, y1, x2, y2, "", "frame 1e300"], "frame"),
        ([rec, "2.5", x1, y1, x2, y2, "", "frame 2.5"], "frame"),
        ([rec, -1, x1, y1, x2, y2, "", "frame -1"], "frame"),
        ([rec, "", x1, y1, x2, y2, "", "no frame"], "frame"),
        ([rec, 0, "", y1, x2, y2, "", "no p1_x"], "p1_x"),
        ([rec, 0, x1, "nan", x2, y2, "", "nan p1_y"], "p1_y"),
        ([rec, 0, x1, y1, "inf", y2, "", "inf p2_x"], "p2_x"),
        ([rec, 0, x1, y1, x2, "abc", "", "text p2_y"], "p2_y"),
        (["", 0, x1, y1, x2, y2, "", "no source"], "source"),
        (["oak", 0, x1, y1, x2, y2, "", "live source"], "source"),
        ([rec, 0, x1, y1, x2, y2, "magic", "bad method"], "method"),
        ([rec, "", "", y1, x2, y2, "", "two bad cells"], "frame,p1_x"),
    ]


def _table(path, rec, frame_truth, bad) -> dict[str, str]:
    """A table of valid rows (two frames, two methods) with the bad rows between them; label -> expected field."""
    (x1, y1), (x2, y2) = frame_truth
    rows = [[rec, i, x1 + d, y1, x2 - d, y2, m, f"ok {i} {d} {m}"] for i in (0, 1) for d in (0, 3) for m in ("robust", "basic")]
    want = {}
    for k, (row, fld) in enumerate(bad):
        rows.insert(2 * k % len(rows), row)
        want[row[-1]] = fld
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        w.writerows(rows)
    return want


@pytest.mark.slow
def test_every_bad_row_is_an_error_row_naming_its_field(archive, tmp_path):
    rec = archive / "rec_poster"
    t = truth(rec, 0)
    p1, p2 = t["p1_px"], t["p2_px"]
    table = tmp_path / "mixed.csv"
    want = _table(table, str(rec), (p1, p2), _bad_rows(str(rec), p1, p2))
    tasks = read_tasks(table)
    assert len(tasks) == 8 + len(want)
    results = {}
    for name, ex in (("inproc", InProcessExecutor()), ("pool", PoolExecutor(2))):
        with ex:
            summary = run_batch(tasks, tmp_path / f"{name}.parquet", ex)
        results[name] = stable(tmp_path / f"{name}.parquet")
        assert summary["rows"] == len(tasks) and summary["errors"]["type"] == {"TaskError": len(want)}
    close_readers()
    rows = results["inproc"]
    assert results["pool"] == rows and [r["task"] for r in rows] == list(range(len(tasks)))  # one row per task
    by_label = {r["label"]: r for r in rows}
    frames = [open_recording(rec).frame(i) for i in (0, 1)]
    for label, r in by_label.items():
        if label.startswith("ok "):
            _, i, d, m = label.split()
            x1, y1, x2, y2 = p1[0] + int(d), p1[1], p2[0] - int(d), p2[1]
            assert r["error"] is None and r["distance_m"] == measure_distance(frames[int(i)], (x1, y1), (x2, y2), MeasureOptions(method=m)).distance_m
        else:
            assert r["error_type"] == "TaskError" and r["error_field"] == want[label], label
            assert r["distance_m"] is None and r["opt_method"] is None
            for f in want[label].split(","):
                assert f in r["error"], (label, r["error"])
    assert by_label["frame 2^63"]["frame"] is None and str(2**63) in by_label["frame 2^63"]["error"]
    assert "2^53 - 1" in by_label["frame 2^53 + 1"]["error"] and "live camera" in by_label["live source"]["error"]
    assert by_label["no p1_x"]["p1_x"] is None and by_label["no p1_x"]["frame"] == 0  # the readable cells are kept
    # the command line: the table runs, and the summary counts the error rows by type and field
    res = invoke(["batch", str(table), "--out", str(tmp_path / "cli.parquet"), "--workers", "1"])
    assert f"{len(tasks)} tasks measured ({len(want)} error rows)" in res
    assert f"error rows by type: TaskError {len(want)}; by field: " in res
    fields = dict(item.rsplit(" ", 1) for item in res.split("by field: ")[1].split(", "))
    assert {k: int(v) for k, v in fields.items()} == {"frame": 7, "p1_x": 2, "p1_y": 1, "p2_x": 1, "p2_y": 1, "source": 2, "method": 1}


@pytest.mark.slow
def test_on_ray_data_the_workers_parse_bad_rows_as_this_process_does(archive, tmp_path, ray_session):
    """On Ray the workers read and parse the table (Ray Data): a CSV of every kind of bad cell, a
    JSONL table with lines that are no objects and a Parquet table of several row groups (read by
    several tasks, row numbers continued across them) give the rows of a run in this process."""
    import pyarrow as pa

    from batch.executors import RayExecutor
    from batch.tasks import TableFile

    rec = archive / "rec_poster"
    t = truth(rec, 0)
    tables = [tmp_path / "mixed.csv", tmp_path / "lines.jsonl", tmp_path / "groups.parquet"]
    _table(tables[0], str(rec), (t["p1_px"], t["p2_px"]), _bad_rows(str(rec), t["p1_px"], t["p2_px"]))
    with tables[0].open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    tables[1].write_text("".join(json.dumps(r) + "\n" if k % 5 else "[1, 2]\n" for k, r in enumerate(rows)))
    pq.write_table(pa.Table.from_pylist(rows), tables[2], row_group_size=4)
    assert pq.ParquetFile(tables[2]).metadata.num_row_groups == 6
    with RayExecutor() as ray_ex:
        for table in tables:
            with InProcessExecutor() as ex:
                run_batch(read_tasks(table), tmp_path / f"{table.stem}-here.parquet", ex)
            summary = run_batch(TableFile.at(table), tmp_path / f"{table.stem}-ray.parquet", ray_ex)
            assert summary["rows"] == len(rows) and summary["error_rows"] > 0, table.name
            assert stable(tmp_path / f"{table.stem}-ray.parquet") == stable(tmp_path / f"{table.stem}-here.parquet"), table.name
    close_readers()


def test_jsonl_and_parquet_tables_with_bad_rows(archive, tmp_path):
    rec = str(archive / "rec_poster")
    t = truth(archive / "rec_poster", 0)
    good = {"source": rec, "frame": 0, "p1_x": t["p1_px"][0], "p1_y": t["p1_px"][1], "p2_x": t["p2_px"][0], "p2_y": t["p2_px"][1]}
    lines = [json.dumps(good), "[1, 2]", "{not json", json.dumps({**good, "frame": 2**64}), json.dumps({**good, "p1_x": None}),
             json.dumps({**good, "frame": True}), json.dumps({**good, "window": 4}), json.dumps({k: v for k, v in good.items() if k != "p2_y"})]  # fmt: skip
    table = tmp_path / "t.jsonl"
    table.write_text("\n".join(lines) + "\n")
    out = tmp_path / "j.parquet"
    invoke(["batch", str(table), "--out", str(out), "--workers", "1"])
    rows = pq.read_table(out).to_pylist()
    assert [r["error_field"] for r in rows] == [None, "row", "row", "frame", "p1_x", "frame", "window", "p2_y"]
    assert rows[0]["distance_m"] > 0 and "line 2 is not a JSON object" in rows[1]["error"] and "window=4" in rows[6]["error"]
    # the same rows as Parquet (typed columns: NaN and null cells)
    import pyarrow as pa

    pq.write_table(pa.table({"source": [rec, rec], "frame": [0, 1], "p1_x": [good["p1_x"], math.nan], "p1_y": [good["p1_y"], None],
                             "p2_x": [good["p2_x"]] * 2, "p2_y": [good["p2_y"]] * 2}), tmp_path / "t.parquet")  # fmt: skip
    invoke(["batch", str(tmp_path / "t.parquet"), "--out", str(tmp_path / "p.parquet"), "--workers", "1"])
    rows = pq.read_table(tmp_path / "p.parquet").to_pylist()
    assert rows[0]["error"] is None and rows[1]["error_field"] == "p1_x,p1_y"
    close_readers()


def test_a_csv_saved_by_excel_with_a_byte_order_mark_reads(archive, tmp_path):
    t = truth(archive / "rec_poster", 1)
    table = tmp_path / "excel.csv"
    text = "source,frame,p1_x,p1_y,p2_x,p2_y\r\n" + f"{archive / 'rec_poster'},1,{t['p1_px'][0]},{t['p1_px'][1]},{t['p2_px'][0]},{t['p2_px'][1]}\r\n"
    table.write_bytes(b"\xef\xbb\xbf" + text.encode())
    (task,) = read_tasks(table)
    assert task.error is None and task.frame == 1
    out = tmp_path / "r.parquet"
    invoke(["batch", str(table), "--out", str(out), "--workers", "1"])
    (row,) = pq.read_table(out).to_pylist()
    assert row["distance_m"] == pytest.approx(t["length_m"], rel=0.03)
    close_readers()


def test_a_row_with_more_cells_than_the_header(archive, tmp_path):
    table = tmp_path / "long.csv"
    table.write_text(f"source,frame,p1_x,p1_y,p2_x,p2_y\n{archive / 'rec_poster'},0,1,2,3,4,5,6\n")
    (task,) = read_tasks(table)
    assert task.error_field == "row" and "2 more cell(s)" in task.error
    res = CliRunner().invoke(cli, ["batch", str(table), "--out", str(tmp_path / "r.parquet"), "--workers", "1"])
    assert res.exit_code == 0 and "by field: row 1" in " ".join(res.output.split())


# A row held as a dict costs ~830 B at any row count. The Parquet reader turns PARQUET_BATCH_ROWS rows
# into dicts at a time: a fixed buffer that stays under the per-task bounds only at about 5x that many
# rows, so the test reads it 256 at a time (the same code path; 4096 rows would need ~20,000 here).
@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".parquet"])
def test_a_table_is_parsed_row_by_row_not_held_as_dicts(tmp_path, suffix, monkeypatch):
    """Reading ``n`` rows keeps them as columns: under 200 B a task with a text column carried
    through (~830 B as Task objects), and peaks at under twice that (every row was once held as a
    dict), whatever the table type; the tasks are the same."""
    import tracemalloc

    import pyarrow as pa

    import batch.tasks

    monkeypatch.setattr(batch.tasks, "PARQUET_BATCH_ROWS", 256)
    n = 5_000
    (tmp_path / "rec").mkdir()
    rows = [{"source": "rec", "frame": i % 50, "p1_x": 100.0 + i % 7, "p1_y": 200.0, "p2_x": 900.0, "p2_y": 210.0,
             "method": "robust", "label": f"L{i}"} for i in range(n)]
    tables = {}
    for name, part in (("warm", rows[:100]), ("t", rows)):
        table = tables[name] = tmp_path / f"{name}{suffix}"
        if suffix == ".csv":
            with table.open("w", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(part)
        elif suffix == ".jsonl":
            table.write_text("".join(json.dumps(r) + "\n" for r in part))
        else:
            pq.write_table(pa.Table.from_pylist(part), table)
    del rows
    read_tasks(tables["warm"])  # caches (sources, option checks) filled before measuring
    tracemalloc.start()
    try:
        tasks = read_tasks(tables["t"])
        kept, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    print(f"{suffix}: {kept / len(tasks):.0f} B per task kept, peak {peak / len(tasks):.0f} B per task")
    assert len(tasks) == n and all(t.error is None for t in tasks)
    assert tasks[8].p1 == (101.0, 200.0) and tasks[8].frame == 8 and tasks[8].extra["label"] == "L8"
    assert kept < 200 * len(tasks) and peak < 2 * kept


def test_shape_cells_from_csv_jsonl_and_parquet(tmp_path):
    """A shape's clicks read as JSON text (CSV) or as lists (JSONL, Parquet); every bad shape cell is
    its row's error naming the field; a table of shapes only needs no p1_x..p2_y columns."""
    import pyarrow as pa

    (tmp_path / "rec").mkdir()
    good = [
        {"kind": "box", "points": [[10, 20]]},
        {"kind": "Height", "points": [[10, 20]], "on": [[5, 60]]},
        {"kind": "height", "points": [[10, 20]], "on": [[1, 60], [9, 60], [5, 70]]},
        {"kind": "path", "points": [[1, 2], [3, 4]], "on": []},
        {"kind": "area", "points": [[1, 2], [30, 4], [20, 40]]},
    ]
    bad = [
        ({"kind": "circle", "points": [[1, 2]]}, "kind"),
        ({"kind": "box", "points": [[1, 2], [3, 4]]}, "points"),
        ({"kind": "height", "points": []}, "points"),
        ({"kind": "area", "points": [[1, 2], [3, 4]]}, "points"),
        ({"kind": "path", "points": [[1, 2, 3], [3, 4]]}, "points"),
        ({"kind": "path", "points": [["a", 2], [3, 4]]}, "points"),
        ({"kind": "path", "points": {"x": 1}}, "points"),
        ({"kind": "path", "points": [[1, 2], [3, 4]], "on": [[1, 2]]}, "on"),
        ({"kind": "height", "points": [[1, 2]], "on": [[1, 2], [3, 4]]}, "on"),
        ({"kind": "height", "points": [[1, 2]], "on": [[1, None]]}, "on"),
        ({"kind": "box"}, "points"),
    ]
    rows = [{"source": "rec", "frame": 0, **g} for g in good] + [{"source": "rec", "frame": 0, **b} for b, _ in bad]
    with (tmp_path / "t.jsonl").open("w") as fh:
        fh.writelines(json.dumps(r) + "\n" for r in rows)
    with (tmp_path / "t.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["source", "frame", "kind", "points", "on"])
        w.writeheader()
        w.writerows({**r, **{k: json.dumps(r[k]) for k in ("points", "on") if k in r}} for r in rows)
    text = (tmp_path / "t.csv").read_text().splitlines()
    (tmp_path / "t.csv").write_text("\n".join([*text, 'rec,0,path,"[[1, 2], [3", ', "rec,0,path,,"]) + "\n")  # no JSON; no points

    def typed(r: dict) -> bool:  # what a Parquet list<list<double>> column can hold
        pts = r.get("points", [])
        return isinstance(pts, list) and all(len(p) == 2 and not isinstance(p[0], str) for p in pts) and "null" not in json.dumps(r.get("on", []))

    parquet_bad = [f for b, f in bad if typed(b)]
    pq.write_table(pa.Table.from_pylist([{**r, "points": r.get("points"), "on": r.get("on")} for r in rows if typed(r)]), tmp_path / "t.parquet")
    for name in ("t.jsonl", "t.csv", "t.parquet"):
        tasks = list(read_tasks(tmp_path / name))
        if name != "t.parquet":
            assert len(tasks) == len(rows) + (2 if name == "t.csv" else 0)
        for t, g in zip(tasks, good):
            assert t.error is None and t.kind == g["kind"].lower() and t.p1 == (None, None), (name, t)
            assert t.points == tuple(tuple(float(v) for v in p) for p in g["points"])
            assert t.on == (tuple(tuple(float(v) for v in p) for p in g["on"]) if g.get("on") else None)
        expected = parquet_bad if name == "t.parquet" else [f for _, f in bad] + (["points", "points"] if name == "t.csv" else [])
        assert [t.error_field for t in tasks[len(good):]] == expected, name
        assert all(t.error and "TaskError" not in t.error for t in tasks[len(good):])
    assert "at least 3" in read_tasks(tmp_path / "t.jsonl")[len(good) + 3].error
    # a segment row in a table of shapes lacks its clicks; a table with neither kind of clicks is refused
    (tmp_path / "s.jsonl").write_text(json.dumps({"source": "rec", "frame": 0, "points": [[1, 2]]}) + "\n")
    (seg,) = read_tasks(tmp_path / "s.jsonl")
    assert seg.error_field == "p1_x,p1_y,p2_x,p2_y,points" and seg.kind == "segment"
    (tmp_path / "n.jsonl").write_text(json.dumps({"source": "rec", "frame": 0, "kind": "box"}) + "\n")
    with pytest.raises(Exception, match="lacks the column"):
        read_tasks(tmp_path / "n.jsonl")
