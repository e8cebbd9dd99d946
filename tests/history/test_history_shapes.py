"""Shape rows in the history: a database of the schema before shapes opens and its rows read as
segments; shape rows (real core answers on a simulated box, 320x180) read back, filter by kind, and
export to CSV and JSON as stored, formula-safe, a segment's cells unchanged."""

from __future__ import annotations

import csv
import io
import json
import sqlite3
from decimal import Decimal

import pytest
from factories import wall_frame

from history import schema
from history.export import CSV_COLUMNS, SHAPE_CELLS, csv_chunks, json_chunks, supported_decimals
from history.records import row_values
from history.store import Store
from measure import measure_area, measure_box, measure_height
from sim.shapes import box_case

SEGMENT = {
    "distance_m": 1.25, "method": "robust", "fit": "line", "p1_m": [-0.5, 0.1, 2.0], "p2_m": [0.7, 0.1, 2.2],
    "basic_distance_m": 1.2, "uncertainty_m": 0.004, "n_samples": 3, "n_valid": 3, "n_support": 2,
    "samples_px": [[1.0, 2.0], [2.0, 2.0]], "support": [True, False], "gap_detected": False, "warnings": [],
    "elapsed_ms": 2.0, "quality": "good", "reasons": [], "interval_m": [1.24, 1.26],
}  # fmt: skip


def _old_database(path) -> None:
    """A history database as the schema before shapes wrote it (every column but ``kind``), one
    segment in it, written through the same values the store inserts."""
    columns = schema.MEASUREMENTS_COLUMNS + tuple((c, d) for t, c, d in schema.MIGRATIONS if t == "measurements" and c != "kind")
    frames = schema.FRAMES_COLUMNS + tuple((c, d) for t, c, d in schema.MIGRATIONS if t == "frames")
    with sqlite3.connect(path) as db:
        for name, cols in (("frames", frames), ("measurements", columns)):
            db.execute(f"CREATE TABLE {name} ({', '.join(f'{c} {d}' for c, d in cols)})")
        db.execute(schema.insert_sql("frames", schema.FRAME_INSERT), ("old", "old.frame", 320, 240, 0.0, "sim", 1.0, 10))
        values = row_values(1.0, 7, "old", "sim", (10, 20), (200, 30), {"window": 5}, SEGMENT, None, {"frame_index": 3})
        old_insert = schema.MEASUREMENT_INSERT[:-1]  # the columns before kind
        assert schema.MEASUREMENT_INSERT[-1] == "kind"
        db.execute(schema.insert_sql("measurements", old_insert), values[:-1])


@pytest.fixture(scope="module")
def box():
    return box_case(1, range_m=1.0, variant="plain", width=320, height=180)


def _add_shapes(store: Store, box) -> dict[str, dict]:
    """A box, a height and an area on the box case's frame, as the service stores them."""
    f = box.frame
    cx, cy = box.click_px
    inner = [(cx + 0.7 * (x - cx), cy + 0.7 * (y - cy)) for x, y in box.corners_px]
    answers = {
        "box": (measure_box(f, box.click_px), [box.click_px], None),
        "height": (measure_height(f, box.click_px, [(cx, 170.0)]), [box.click_px], [(cx, 170.0)]),
        "area": (measure_area(f, inner), inner, None),
    }
    out = {}
    for kind, (res, points, on) in answers.items():
        draw = [[1.0, 2.0], [3.0, 4.0]]
        out[kind] = store.add_shape(frame_id=5, frame_uid="u", frame=f, source="sim", kind=kind, points=points, on=on,
                                    options={"method": "robust"}, result=res.to_dict(), draw_px=draw, context={"frame_index": 2})
    return out


def test_a_database_of_the_schema_before_shapes_opens_and_reads_as_segments(tmp_path, box):
    db = tmp_path / "old.db"
    _old_database(db)
    with sqlite3.connect(db) as con:
        assert "kind" not in {r[1] for r in con.execute("PRAGMA table_info(measurements)")}
    ro = schema.open_read_only(db)  # the batch reads an unmigrated database as it is
    assert [r["id"] for r in schema.measurement_inputs(ro)] == [1]
    ro.close()
    store = Store(db)
    try:
        old = store.record(1)
        assert old["kind"] == "segment" and old["distance_m"] == 1.25 and old["p2"] == [200.0, 30.0]
        assert old["samples_px"] == SEGMENT["samples_px"] and old["frame_index"] == 3
        shapes = _add_shapes(store, box)
        assert [r["id"] for r in store.list_slim(kind="segment")] == [1]
        assert [r["kind"] for r in store.list_slim()] == ["area", "height", "box", "segment"]
        assert [r["id"] for r in store.list_slim(kind="box")] == [shapes["box"]["id"]]
        con = schema.open_read_only(db)
        inputs = schema.measurement_inputs(con)  # every kind, a shape with its stored clicks
        assert [(r["id"], r["kind"]) for r in inputs] == [(1, "segment"), *((shapes[k]["id"], k) for k in ("box", "height", "area"))]
        assert [json.loads(r["extra"]).get("shape", {}).get("on") for r in inputs] == [None, None, [[box.click_px[0], 170.0]], None]
        con.close()
    finally:
        store.close()


def test_shape_records_read_back_as_answered(tmp_path, box):
    store = Store(tmp_path / "h.db")
    try:
        shapes = _add_shapes(store, box)
        for kind, answered in shapes.items():
            assert store.record(answered["id"]) == answered, kind
        b, h, a = shapes["box"], shapes["height"], shapes["area"]
        core = measure_box(box.frame, box.click_px)
        assert b["dimensions_m"] == list(core.dimensions_m) and b["dimension_sigmas_m"] == list(core.uncertainty_m)
        assert b["dimensions_m"] == pytest.approx([box.length_m, box.width_m, box.height_m], rel=0.06)
        assert h["value"] == pytest.approx(box.height_m, rel=0.02) and h["on"] == [[box.click_px[0], 170.0]]
        assert a["unit"] == "m2" and a["value"] == pytest.approx(0.49 * box.length_m * box.width_m, rel=0.12)
        assert (b["frame_index"], b["created_at"]) == (2, b["created"]) and "distance_m" not in b  # no segment fields
    finally:
        store.close()


def test_csv_and_json_rows_are_the_stored_rows(tmp_path, box):
    store = Store(tmp_path / "h.db")
    try:
        seg = store.add(frame_id=1, frame_uid="w", frame=wall_frame(0), source="sim", p1=(10, 20), p2=(200, 30),
                        options={"window": 5}, result=SEGMENT)
        shapes = _add_shapes(store, box)
        store.annotate(shapes["box"]["id"], name="=HYPERLINK(\"x\")", note="-1+2")
        records = [store.record(seg["id"])] + [store.record(s["id"]) for s in shapes.values()]
        got = json.loads(b"".join(json_chunks(store.batches(2, arrays=True))))["measurements"]
        assert got == records  # every field, a segment with its arrays, a shape without any
        rows = list(csv.DictReader(io.StringIO("".join(csv_chunks(store.batches(2), "cm")), newline="")))
        assert tuple(rows[0]) == CSV_COLUMNS and [r["kind"] for r in rows] == ["segment", "box", "height", "area"]
        s, b, h, a = rows
        assert (s["distance"], s["p2_x_px"], s["uncertainty_1sigma"]) == ("125.00", "200.0", "0.4")
        assert all(s[c] == "" for c in CSV_COLUMNS[SHAPE_CELLS:])  # a segment's shape cells blank
        box_rec = records[1]
        for name, v, sigma in zip(("length", "width", "height"), box_rec["dimensions_m"], box_rec["dimension_sigmas_m"]):
            assert Decimal(b[name]) == Decimal(f"{v * 100:.{supported_decimals(sigma, 100.0)}f}"), name
            assert float(b[f"{name}_1sigma"]) == pytest.approx(sigma * 100, rel=0.05)
        assert (b["value"], b["uncertainty_1sigma"], b["distance"], b["fit"], b["quality"]) == ("", "", "", "box", box_rec["quality"])
        assert (b["name"], b["note"]) == ("'=HYPERLINK(\"x\")", "'-1+2")  # formulas neutralised as for a segment
        hr, ar = records[2], records[3]
        assert float(h["value"]) == pytest.approx(hr["value"] * 100, abs=10 ** -supported_decimals(hr["uncertainty"], 100.0))
        assert h["value_unit"] == "cm" and a["value_unit"] == "cm2"
        assert float(a["value"]) == pytest.approx(ar["value"] * 1e4, abs=10 ** -supported_decimals(ar["uncertainty"], 1e4))
        assert float(a["interval_low"]) == pytest.approx(ar["interval"][0] * 1e4, abs=10 ** -supported_decimals(ar["uncertainty"], 1e4))
        assert a["points_px"] == "; ".join(f"{x:.1f} {y:.1f}" for x, y in ar["points"]) and a["length"] == ""
    finally:
        store.close()


def test_a_shape_row_needs_a_shape_kind(tmp_path, box):
    store = Store(tmp_path / "h.db")
    try:
        with pytest.raises(ValueError, match="kind must be one of height, path, area, box"):
            store.add_shape(frame_id=1, frame_uid="u", frame=box.frame, source="sim", kind="circle", points=[(1, 1)],
                            on=None, options={}, result={}, draw_px=[])
        assert store.list_slim() == []
    finally:
        store.close()
