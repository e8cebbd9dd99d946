"""Shapes in a batch: a table that mixes segments, heights, paths, areas and boxes gives the same rows
in this process, a pool and Ray, each answer the core's on the recorded frame; every stored
measurement of a service history, of every kind, is re-measured to the stored answer."""

from __future__ import annotations

import csv
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from batch.executors import InProcessExecutor, PoolExecutor, RayExecutor
from batch.run import close_readers, run_batch
from batch.rows import flatten
from batch.schema import (
    BOX_DIMENSIONS, BOX_SPLIT, BOX_TYPES, SHAPE_IN_TASK, SHAPE_SHARED, SHAPE_TYPES, measurement_column, result_schema, shape_columns,
)
from batch.tasks import read_tasks
from batch_tables import invoke, stable, truth
from device.formats.recording import open_recording
from measure import MeasureOptions, measure_distance, measure_shape

COLUMNS = ["source", "frame", "kind", "p1_x", "p1_y", "p2_x", "p2_y", "points", "on", "method", "label"]


def test_every_field_of_a_shape_answer_has_its_column(shape_rec):
    """A field the core adds to a shape's answer fails here until the result schema has its column."""
    shapes, box, panel = shape_rec
    frame = open_recording(shapes).frame(0)
    answers = {k: measure_shape(frame, k, [box.click_px]) for k in ("box", "height")}
    split = {pattern.format(d) for pattern, _ in BOX_SPLIT.values() for d in BOX_DIMENSIONS}
    assert set(answers["height"].to_dict()) == set(SHAPE_TYPES) | set(SHAPE_SHARED) | set(SHAPE_IN_TASK) - {"click_px"}
    assert set(answers["box"].to_dict()) == (set(BOX_TYPES) - split) | set(BOX_SPLIT) | set(SHAPE_SHARED) | {"click_px"}
    schema = result_schema()
    for kind, answer in answers.items():
        cols = shape_columns(answer)
        assert set(cols) <= set(schema.names), kind
        assert all(str(schema.field(c).type).startswith("list") == isinstance(v, list) for c, v in cols.items() if v is not None), kind
    b = shape_columns(answers["box"])
    assert [b[f"{d}_sigma_m"] for d in BOX_DIMENSIONS] == list(answers["box"].uncertainty_m)
    assert [b[f"{d}_interval_m"] for d in BOX_DIMENSIONS] == [list(i) for i in answers["box"].intervals_m]


def _mixed_table(path, poster, shapes, box, panel) -> dict[str, dict]:
    """Segments and every shape kind, valid and not, interleaved; label -> what the row asks."""
    t = truth(poster, 0)
    (x1, y1), (x2, y2) = t["p1_px"], t["p2_px"]
    cx, cy = box.click_px
    floor = [[20, 200], [150, 200], [150, 265], [20, 265]]  # a region of the floor beside the box
    corners = [list(p) for p in panel.clicks_px]
    asks = {
        "segment": dict(source=poster, frame=0, kind="", p=[x1, y1, x2, y2]),
        "segment named": dict(source=poster, frame=1, kind="segment", p=[x1, y1, x2, y2], method="basic"),
        "box": dict(source=shapes, frame=0, kind="box", points=[[cx, cy]]),
        "box paper": dict(source=shapes, frame=0, kind="BOX", points=[[cx, cy]], method="paper"),
        "height found": dict(source=shapes, frame=0, kind="height", points=[[cx, cy]]),
        "height on a click": dict(source=shapes, frame=0, kind="height", points=[[cx, cy]], on=[[cx, 260]]),
        "height on a region": dict(source=shapes, frame=0, kind="height", points=[[cx, cy]], on=floor),
        "area": dict(source=shapes, frame=1, kind="area", points=corners),
        "path": dict(source=shapes, frame=1, kind="path", points=corners[:3]),
        "box on the floor": dict(source=shapes, frame=0, kind="box", points=[[cx, 262]], error=("MeasureError", None)),
        "cube": dict(source=shapes, frame=0, kind="cube", points=[[cx, cy]], error=("TaskError", "kind")),
        "box of two": dict(source=shapes, frame=0, kind="box", points=[[cx, cy], [cx, cy + 5]], error=("TaskError", "points")),
        "area of two": dict(source=shapes, frame=1, kind="area", points=corners[:2], error=("TaskError", "points")),
        "path on": dict(source=shapes, frame=1, kind="path", points=corners[:2], on=[[1, 2]], error=("TaskError", "on")),
        "height on two": dict(source=shapes, frame=0, kind="height", points=[[cx, cy]], on=floor[:2], error=("TaskError", "on")),
        "segment with points": dict(source=poster, frame=0, kind="", p=[x1, y1, x2, y2], points=[[1, 2]], error=("TaskError", "points")),
        "no json": dict(source=shapes, frame=1, kind="path", points="[[1, 2], [3", error=("TaskError", "points")),
        "a nan click": dict(source=shapes, frame=1, kind="path", points="[[1, 2], [NaN, 4]]", error=("TaskError", "points")),
        "no points": dict(source=shapes, frame=0, kind="box", error=("TaskError", "points")),
    }
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for label, a in asks.items():
            pts = a.get("points")
            cell = lambda v: "" if v is None else (v if isinstance(v, str) else json.dumps(v))  # noqa: E731
            w.writerow([a["source"], a["frame"], a["kind"], *(a.get("p") or [""] * 4), cell(pts), cell(a.get("on")), a.get("method", ""), label])
    return asks


def _core(frame, a) -> dict:
    """The answer columns the core gives for ``a`` on ``frame``."""
    options = MeasureOptions(method=a.get("method", "robust"))
    kind = a["kind"].lower() or "segment"
    if kind == "segment":
        answer = {measurement_column(k): v for k, v in measure_distance(frame, tuple(a["p"][:2]), tuple(a["p"][2:]), options).to_dict().items()}
    else:
        on = [tuple(p) for p in a["on"]] if a.get("on") else None
        answer = shape_columns(measure_shape(frame, kind, [tuple(p) for p in a["points"]], on, options))
    return {k: flatten(v) for k, v in answer.items() if k != "elapsed_ms"}


@pytest.mark.slow
def test_a_mixed_table_gives_the_same_rows_on_every_executor(archive, shape_rec, tmp_path, ray_session):
    shapes, box, panel = shape_rec
    table = tmp_path / "mixed.csv"
    asks = _mixed_table(table, str(archive / "rec_poster"), str(shapes), box, panel)
    tasks = read_tasks(table)
    results = {}
    for name, make in (("inproc", InProcessExecutor), ("pool", lambda: PoolExecutor(2)), ("ray", RayExecutor)):
        with make() as ex:
            summary = run_batch(tasks, tmp_path / f"{name}.parquet", ex)
        assert summary["rows"] == len(asks)
        results[name] = stable(tmp_path / f"{name}.parquet")
    close_readers()
    rows = results["inproc"]
    assert results["pool"] == rows and results["ray"] == rows and [r["task"] for r in rows] == list(range(len(asks)))
    # one schema, every column in every row, of every kind
    schema = pq.read_schema(tmp_path / "inproc.parquet")
    assert schema.names == result_schema({"label": list(asks)}).names
    assert {"value", "unit", "uncertainty", "interval", "length_sigma_m", "height_interval_m"} <= set(schema.names)
    frames = {(str(archive / "rec_poster"), i): open_recording(archive / "rec_poster").frame(i) for i in (0, 1)}
    frames |= {(str(shapes), i): open_recording(shapes).frame(i) for i in (0, 1)}
    by_label = {r["label"]: r for r in rows}
    for label, a in asks.items():
        r = by_label[label]
        if "error" in a:
            error_type, fld = a["error"]
            assert r["error_type"] == error_type and r["error_field"] == fld, (label, r["error"])
            assert r["value"] is r["length_m"] is r["distance_m"] is None
            continue
        assert r["error"] is None, (label, r["error"])
        want = _core(frames[(a["source"], a["frame"])], a)
        for k, v in want.items():
            assert r[k] == v, (label, k)
        kind = a["kind"].lower() or "segment"
        assert r["kind"] == kind and r["quality"] in ("good", "check", "unreliable")
        empty = set(BOX_TYPES) if kind != "box" else set(SHAPE_TYPES)
        assert all(r[c] is None for c in empty), label  # the other kinds' columns are null
    # the answers are measurements of the simulated scenes
    b = by_label["box"]
    assert [b["length_m"], b["width_m"], b["height_m"]] == pytest.approx([box.length_m, box.width_m, box.height_m], rel=0.06)
    assert all(b[f"{d}_sigma_m"] > 0 and len(b[f"{d}_interval_m"]) == 2 for d in ("length", "width", "height"))
    for label in ("height found", "height on a click", "height on a region"):
        assert by_label[label]["value"] == pytest.approx(box.height_m, rel=0.02) and by_label[label]["unit"] == "m"
    assert by_label["area"]["value"] == pytest.approx(panel.area_m2, rel=0.03) and by_label["area"]["unit"] == "m2"
    path = by_label["path"]
    assert path["value"] == pytest.approx(sum(path["parts"])) and len(path["parts"]) == 2
    assert by_label["cube"]["kind"] is None and by_label["box"]["points"] == [list(box.click_px)]
    assert by_label["height on a region"]["on"] == asks["height on a region"]["on"]
    # diff: the same file has every answer unchanged; export writes the clicks and corners as JSON
    d = json.loads(invoke(["batch", "diff", str(tmp_path / "inproc.parquet"), str(tmp_path / "pool.parquet"), "--json"]))
    answered = sum(1 for a in asks.values() if "error" not in a)
    assert d["compared"] == d["unchanged_exactly"] == answered and d["moved_beyond_uncertainty"] == 0
    assert set(d["changes_by_kind"]) == {"segment", "box", "height", "area", "path"} and d["changes_by_kind"]["area"]["unit"] == "m2"
    invoke(["batch", "export", str(tmp_path / "inproc.parquet"), "--csv", str(tmp_path / "r.csv")])
    with (tmp_path / "r.csv").open(newline="") as fh:
        exported = {r["label"]: r for r in csv.DictReader(fh)}
    assert json.loads(exported["box"]["corners_px"]) == b["corners_px"] and float(exported["box"]["width_m"]) == b["width_m"]
    assert json.loads(exported["area"]["points"]) == by_label["area"]["points"] and exported["area"]["length_m"] == ""


def _history(db, shapes, box, panel, poster) -> dict[int, dict]:
    """A service history, written by the service on the recordings' frames: two segments and each shape kind."""
    from fastapi.testclient import TestClient

    from device.formats.recording import ReplayConfig, ReplaySource
    from service.app import create_app

    cx, cy = box.click_px
    corners = [list(p) for p in panel.clicks_px]
    t = truth(poster, 0)
    box_frame, panel_frame = open_recording(shapes).frame(0), open_recording(shapes).frame(1)
    asks = [
        (open_recording(poster).frame(0), "segment", {"p1": list(t["p1_px"]), "p2": list(t["p2_px"])}, {}),
        (box_frame, "box", {"points": [[cx, cy]]}, {}),
        (box_frame, "box", {"points": [[cx, cy]]}, {"seed": 3}),
        (box_frame, "height", {"points": [[cx, cy]]}, {}),
        (box_frame, "height", {"points": [[cx, cy]], "on": [[cx, 260]]}, {}),
        (panel_frame, "area", {"points": corners}, {}),
        (panel_frame, "path", {"points": corners[:3]}, {"method": "basic"}),
        (open_recording(poster).frame(1), "segment", {"p1": list(t["p1_px"]), "p2": list(t["p2_px"])}, {"method": "paper"}),
    ]
    factory = lambda: ReplaySource(ReplayConfig(poster, loop=True))  # noqa: E731
    stored = {}
    with TestClient(create_app(factory, db_path=db, capture_fps=5.0), base_url="http://127.0.0.1") as client:
        for frame, kind, clicks, options in asks:
            fid = client.app.state.ring.push(frame, frozen=True).id
            if kind == "segment":
                r = client.post("/api/measure", json={"frame_id": fid, **clicks, "options": options})
            else:
                r = client.post("/api/shapes", json={"frame_id": fid, "kind": kind, **clicks, "options": options})
            assert r.status_code == 200, r.text
            stored[r.json()["id"]] = client.get(f"/api/measurements/{r.json()['id']}").json()
    return stored


@pytest.mark.slow
def test_from_history_re_measures_every_kind_to_the_stored_answer(archive, shape_rec, tmp_path):
    shapes, box, panel = shape_rec
    db = tmp_path / "history.db"
    stored = _history(db, shapes, box, panel, archive / "rec_poster")
    assert sorted(s["kind"] for s in stored.values()) == ["area", "box", "box", "height", "height", "path", "segment", "segment"]
    out = tmp_path / "h.parquet"
    res = invoke(["batch", "--from-history", str(db), "--out", str(out), "--workers", "2"])
    assert f"{len(stored)} tasks measured (0 error rows)" in res
    rows = pq.read_table(out).to_pylist()
    assert [r["history_id"] for r in rows] == sorted(stored)  # one row per stored measurement, of every kind
    for r in rows:
        want = stored[r["history_id"]]
        assert r["error"] is None and r["kind"] == want["kind"] and r["frame_uid"] == want["frame_uid"]
        assert (r["quality"], r["reasons"]) == (want["quality"], want["reasons"]), r["kind"]  # the same verdict
        assert {k: r[f"opt_{k}"] for k in want["options"]} == want["options"]
        if want["kind"] == "segment":
            assert (r["distance_m"], r["uncertainty_m"], r["interval_m"]) == (want["distance_m"], want["uncertainty_m"], want["interval_m"])
        elif want["kind"] == "box":
            assert [r["length_m"], r["width_m"], r["height_m"]] == want["dimensions_m"]
            assert [r["length_sigma_m"], r["width_sigma_m"], r["height_sigma_m"]] == want["dimension_sigmas_m"]
            assert [r["length_interval_m"], r["width_interval_m"], r["height_interval_m"]] == want["dimension_intervals_m"]
            assert r["corners_px"] == want["result"]["corners_px"] and r["points"] == want["points"]
        else:
            assert (r["value"], r["unit"], r["uncertainty"], r["interval"]) == (want["value"], want["unit"], want["uncertainty"], want["interval"])
            assert r["points"] == want["points"] and r["on"] == want["on"] and r["points_m"] == want["result"]["points_m"]
    heights = [r for r in rows if r["kind"] == "height"]
    assert heights[0]["on"] is None and heights[1]["on"] == [[box.click_px[0], 260.0]]
    assert np.isclose(heights[1]["value"], box.height_m, rtol=0.02)
    close_readers()


def test_a_stored_shape_whose_clicks_cannot_be_read_is_its_error_row(shape_rec, tmp_path):
    import sqlite3

    from batch.history import history_tasks
    from history.store import Store

    shapes, box, _ = shape_rec
    frame = open_recording(shapes).frame(0)
    db = tmp_path / "h.db"
    store = Store(db)
    try:
        answer = measure_shape(frame, "box", [box.click_px]).to_dict()
        ids = [store.add_shape(frame_id=1, frame_uid="u", frame=frame, source="sim", kind="box", points=[box.click_px], on=None,
                               options={"seed": 2}, result=answer, draw_px=[])["id"] for _ in range(3)]  # fmt: skip
    finally:
        store.close()
    with sqlite3.connect(db) as con:
        con.execute("UPDATE measurements SET extra = ? WHERE id = ?", (json.dumps({"shape": {"points": [[1, 2], [3, 4]]}}), ids[1]))
        con.execute("UPDATE measurements SET kind = 'cone' WHERE id = ?", (ids[2],))
    tasks = history_tasks(db)
    assert [(t.kind, t.error_field) for t in tasks] == [("box", None), ("box", "points"), (None, "kind")]
    assert tasks[0].points == (tuple(box.click_px),) and tasks[0].options == {"seed": 2}
    assert "exactly 1" in tasks[1].error and "'cone'" in tasks[2].error
