"""The streamed exports: the same records as the full decode, across batch boundaries, formula-safe
CSV read back, and a history growing during an export."""

from __future__ import annotations

import csv
import io
import json

import pytest
from factories import wall_frame

from history.export import CSV_COLUMNS, csv_chunks, json_chunks
from history.store import Store

NAMES = ["plain", "=1+2", "-3", "@SUM(A1)", "+x", "tab\there", 'quote "q", comma', "ünïcode ✓", "\rcr", "last"]


def _result(k: int) -> dict:
    return {
        "distance_m": 0.5 + k / 7, "method": "robust", "fit": "line", "p1_m": [-0.25 * k, 0.1, 2.0], "p2_m": [0.3, -0.2, 2.5],
        "basic_distance_m": 0.5, "uncertainty_m": 10.0 ** -(1 + k % 4), "n_samples": 3 + k, "n_valid": 2 + k, "n_support": 1 + k,
        "samples_px": [[float(i), 0.5 * i] for i in range(k + 1)], "support": [i % 2 == 0 for i in range(k + 1)],
        "gap_detected": k % 2 == 1, "warnings": [f"w{k}"] if k % 3 else [], "elapsed_ms": 1.5,
        "quality": "check", "reasons": ["r1", "r2"], "interval_m": [0.4, 0.6 + k],
    }  # fmt: skip


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "h.db")
    frame = wall_frame(0)
    for k, name in enumerate(NAMES):
        rec = s.add(frame_id=k, frame_uid=f"u{k % 3}", frame=frame, source="sim", p1=(1, 2 + k), p2=(30, 4), options={"window": 5}, result=_result(k))
        s.annotate(rec["id"], name=name, note=f"note {k}")
    s.delete(4)  # a gap in the ids
    yield s
    s.close()


@pytest.mark.parametrize("size", [1, 3, 500])
def test_json_export_is_the_full_records_in_batches(store, size):
    chunks = list(json_chunks(store.batches(size, arrays=True)))
    assert len(chunks) == 2 + -(-9 // size)  # opening, one per batch, closing
    got = json.loads(b"".join(chunks))["measurements"]
    assert got == list(reversed(store.list()))  # every field of the decoded records, arrays included
    assert [m["id"] for m in got] == [1, 2, 3, 5, 6, 7, 8, 9, 10]
    assert got[-1]["samples_px"] == [[float(i), 0.5 * i] for i in range(10)] and got[-1]["support"][:3] == [True, False, True]


@pytest.mark.parametrize("size", [2, 500])
def test_csv_export_streams_the_same_text_and_stays_formula_safe(store, size):
    text = "".join(csv_chunks(store.batches(size), "mm", "http://h/"))
    assert text == store.csv("mm", "http://h/")
    rows = list(csv.DictReader(io.StringIO(text, newline="")))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == 9
    kept = [n for k, n in enumerate(NAMES) if k != 3]
    assert [r["name"] for r in rows] == [("'" + n) if n[0] in "=+-@\t\r" else n for n in kept]
    assert rows[1]["p1_X"] == "-250" and rows[1]["distance"] == "643"  # numbers stay numbers, in mm to 1 sigma = 10 mm
    assert rows[-1]["frame_url"] == "http://h/api/measurements/10/color.png"


def test_export_of_an_empty_history_and_bad_units(tmp_path):
    s = Store(tmp_path / "e.db")
    try:
        assert json.loads(b"".join(json_chunks(s.batches(arrays=True)))) == {"measurements": []}
        assert s.csv() == ",".join(CSV_COLUMNS) + "\r\n"
        with pytest.raises(ValueError, match="units must be one of m, cm, mm, in"):
            csv_chunks(s.batches(), "furlong")  # raised before any chunk is sent
    finally:
        s.close()


def test_measurements_stored_during_an_export_are_left_out(store):
    batches = store.batches(4)
    first = next(batches)
    store.add(frame_id=99, frame_uid="u0", frame=wall_frame(0), source="sim", p1=(1, 2), p2=(3, 4), options={}, result=_result(1))
    ids = [r["id"] for r in first] + [r["id"] for b in batches for r in b]
    assert ids == [1, 2, 3, 5, 6, 7, 8, 9, 10]


def test_csv_names_the_source_kind_and_recording_and_older_rows_stay_readable(tmp_path):
    """A measurement on a replay says "replay" and the recording's folder; one stored before the service
    kept them (an existing database: no such keys in its row) exports with those cells empty."""
    s = Store(tmp_path / "k.db")
    try:
        frame = wall_frame(0)
        s.add(frame_id=1, frame_uid="old", frame=frame, source="sim", p1=(1, 2), p2=(30, 4), options={}, result=_result(0))
        s.add(frame_id=2, frame_uid="new", frame=frame, source="replay:rec/desk?loop=1", p1=(1, 2), p2=(30, 4), options={},
              result=_result(1), context={"source_kind": "replay", "recording": "desk", "frame_index": 5, "recorded_source": "sim"})
        rows = list(csv.DictReader(io.StringIO(s.csv(), newline="")))
        got = [(r["source"], r["source_kind"], r["recording"], r["frame_index"]) for r in rows]
        assert got == [("sim", "", "", ""), ("replay:rec/desk?loop=1", "replay", "desk", "5")]
        assert CSV_COLUMNS.index("source_kind") == CSV_COLUMNS.index("source") + 1
        assert s.get(2)["recorded_source"] == "sim" and "source_kind" not in s.get(1)
    finally:
        s.close()
