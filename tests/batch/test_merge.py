"""The bounded-memory merge of result parts: the same file as sorting all rows at once."""

from __future__ import annotations

import io

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from batch.merge import DuplicateTasks, merge_sorted


def _part(path, tasks, with_error=True):
    cols = {"task": pa.array(tasks, pa.int64()), "distance_m": pa.array([t * 0.5 for t in tasks], pa.float64())}
    if with_error:
        cols["error"] = pa.array([None if t % 3 else f"e{t}" for t in tasks], pa.string())
    pq.write_table(pa.table(cols), path)
    return path


def test_parts_in_any_order_merge_in_small_chunks_to_the_sorted_table(tmp_path):
    """60 parts of shuffled task ids (each spanning the whole range: the worst case), an earlier
    file without the ``error`` column, chunks of ~1k rows: every row once, sorted, nulls where a
    file lacked the column, the metadata kept."""
    rng = np.random.default_rng(3)
    ids = rng.permutation(6000)
    earlier = _part(tmp_path / "earlier.parquet", sorted(ids[:1000].tolist()), with_error=False)
    parts = [_part(tmp_path / f"part-{k:03d}.parquet", ids[1000 + 83 * k : 1000 + 83 * (k + 1)].tolist()) for k in range(61)]
    buf = io.BytesIO()
    n = merge_sorted([earlier, *parts], buf, {"depthruler.run": "r1"}, chunk_bytes=20_000)
    out = pq.ParquetFile(io.BytesIO(buf.getvalue()))
    assert n == 6000 and out.num_row_groups > 3  # more than one chunk was written
    t = out.read()
    assert t.column("task").to_pylist() == list(range(6000))
    assert t.column("distance_m").to_pylist() == [i * 0.5 for i in range(6000)]
    early = set(ids[:1000].tolist())
    assert t.column("error").to_pylist() == [None if i in early or i % 3 else f"e{i}" for i in range(6000)]
    assert out.schema_arrow.metadata[b"depthruler.run"] == b"r1"


def test_a_task_in_two_inputs_is_refused(tmp_path):
    a = _part(tmp_path / "a.parquet", [0, 1, 2])
    b = _part(tmp_path / "b.parquet", [5, 2])
    with pytest.raises(DuplicateTasks, match="task 2 is held twice"):
        merge_sorted([a, b], io.BytesIO())
