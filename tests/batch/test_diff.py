"""`batch diff` on hand-built results: repeated clicks pair k-th with k-th, errors and verdicts
counted, parts folders read, options reported."""

import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from batch.diff import diff_results
from batch.results import ResultsError


def _write(path, rows, defaults=None):
    t = pa.Table.from_pylist(rows)
    if defaults is not None:
        t = t.replace_schema_metadata({b"depthruler.defaults": json.dumps(defaults).encode()})
    pq.write_table(t, path)


def _row(task, src, d, u=0.001, err=None, quality="good", p1x=10.0):
    return {"task": task, "source": src, "frame": 0, "frame_uid": None, "p1_x": p1x, "p1_y": 5.0, "p2_x": 90.0,
            "p2_y": 5.0, "distance_m": None if err else d, "uncertainty_m": None if err else u, "error": err,
            "quality": None if err else quality}  # fmt: skip


def test_repeated_clicks_pair_in_order_and_everything_is_counted(tmp_path):
    a_rows = [_row(0, "r1", 1.000), _row(1, "r1", 1.010), _row(2, "r2", 2.0), _row(3, "r2", 0.5, err="outside"), _row(4, "r3", 3.0)]
    b_rows = [_row(10, "r1", 1.000), _row(11, "r1", 1.030, quality="check"), _row(12, "r2", 2.0005),
              _row(13, "r2", 0.5), _row(14, "r4", 1.0)]  # fmt: skip
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    _write(a, a_rows, {})
    _write(b, b_rows, {"method": "basic", "window": 7})
    d = diff_results(a, b)
    assert (d["rows_a"], d["rows_b"], d["matched"], d["only_in_a"], d["only_in_b"]) == (5, 5, 4, 1, 1)
    assert d["status"] == {"answered -> answered": 3, "error -> answered": 1}
    assert d["compared"] == 3 and d["unchanged_exactly"] == 1
    # 1.010 -> 1.030 moved beyond 1 mm; 2.0 -> 2.0005 did not
    assert d["moved_beyond_uncertainty"] == 1
    (m,) = d["largest_moves"]
    assert (m["task_a"], m["task_b"], m["kind"], m["answer"]) == (1, 11, "segment", "distance_m") and m["delta"] == pytest.approx(0.02)
    assert d["verdict_changes"] == {"quality": {"good -> check": 1}}
    seg = d["changes_by_kind"]["segment"]
    assert seg["max_abs_change"] == pytest.approx(0.02) and seg["median_abs_change"] == pytest.approx(0.0005) and seg["unit"] == "m"
    assert d["runs"]["b"]["options"] == {"method": "basic", "window": 7}


def test_a_parts_folder_compares_and_a_missing_file_is_a_typed_error(tmp_path):
    parts = tmp_path / "r.parquet.parts"
    parts.mkdir()
    _write(parts / "part-000000.parquet", [_row(0, "r1", 1.0)])
    _write(parts / "part-000001.parquet", [_row(1, "r2", 2.0)])
    whole = tmp_path / "w.parquet"
    _write(whole, [_row(0, "r1", 1.0), _row(1, "r2", 2.0)])
    d = diff_results(whole, parts)
    assert d["matched"] == 2 and d["unchanged_exactly"] == 2 and d["runs"]["b"]["options"] == {}
    with pytest.raises(ResultsError, match="does not exist"):
        diff_results(whole, tmp_path / "nope.parquet")


def _shape(task, kind, points, **answer):
    row = {"task": task, "source": "r", "frame": 0, "frame_uid": None, "kind": kind, "points": points, "error": None, "quality": "good",
           "value": None, "uncertainty": None, "distance_m": None, "uncertainty_m": None, **{f"{d}{s}": None for d in ("length", "width", "height") for s in ("_m", "_sigma_m")}}
    return row | answer


def test_shapes_compare_each_answer_with_its_uncertainty(tmp_path):
    """A box moved when any dimension moved beyond its sigma; a height, path or area by its value; a
    shape pairs with the row of the same kind and clicks, never with a segment on the same frame."""
    box = {"length_m": 0.5, "length_sigma_m": 0.004, "width_m": 0.3, "width_sigma_m": 0.004, "height_m": 0.2, "height_sigma_m": 0.003}
    a_rows = [_shape(0, "box", [[10.0, 20.0]], **box), _shape(1, "area", [[1.0, 1.0], [9.0, 1.0], [9.0, 9.0]], value=0.10, uncertainty=0.002),
              _shape(2, "height", [[10.0, 20.0]], value=0.2, uncertainty=0.002), _shape(3, "box", [[50.0, 20.0]], **box),
              {**_row(4, "r", 1.0), "kind": "segment", "points": None}]  # fmt: skip
    b_rows = [_shape(10, "box", [[10.0, 20.0]], **box | {"width_m": 0.31}), _shape(11, "area", [[1.0, 1.0], [9.0, 1.0], [9.0, 9.0]], value=0.101, uncertainty=0.002),
              _shape(12, "height", [[10.0, 20.0]], value=0.2, uncertainty=0.002), _shape(13, "box", [[50.0, 20.0]], **box | {"height_m": 0.2005}),
              {**_row(14, "r", 1.0), "kind": "segment", "points": None}]  # fmt: skip
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    _write(a, a_rows)
    _write(b, b_rows)
    d = diff_results(a, b)
    assert d["matched"] == 5 and d["compared"] == 5
    assert d["moved_beyond_uncertainty"] == 1 and d["unchanged_exactly"] == 2  # the first box (width); the height and the segment
    (m,) = d["largest_moves"]
    assert (m["task_a"], m["kind"], m["answer"], m["a"], m["b"]) == (0, "box", "width_m", 0.3, 0.31)
    assert d["changes_by_kind"]["area"] == {"unit": "m2", "answers": 1, "median_abs_change": pytest.approx(0.001), "max_abs_change": pytest.approx(0.001)}
    assert d["changes_by_kind"]["box"]["answers"] == 6 and d["changes_by_kind"]["box"]["max_abs_change"] == pytest.approx(0.01)
    # another box click is another measurement: no pair
    _write(b, [_shape(10, "box", [[11.0, 20.0]], **box)])
    assert diff_results(a, b)["matched"] == 0
