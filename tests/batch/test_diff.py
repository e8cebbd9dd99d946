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
    assert d["compared_distances"] == 3 and d["unchanged_exactly"] == 1
    # 1.010 -> 1.030 moved beyond 1 mm; 2.0 -> 2.0005 did not
    assert d["moved_beyond_uncertainty"] == 1
    (m,) = d["largest_moves"]
    assert (m["task_a"], m["task_b"]) == (1, 11) and m["delta_m"] == pytest.approx(0.02)
    assert d["verdict_changes"] == {"quality": {"good -> check": 1}}
    assert d["max_abs_change_m"] == pytest.approx(0.02) and d["median_abs_change_m"] == pytest.approx(0.0005)
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
