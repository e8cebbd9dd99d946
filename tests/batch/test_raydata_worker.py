"""A Ray worker process measures partitions of many runs (Ray keeps its worker processes): each run
must see the archive as it is when that run reaches the worker, not as the worker last opened it."""

from __future__ import annotations

import shutil

from batch.run import close_readers
from batch.schema import result_schema
from batch.taskblocks import to_block
from batch.tasks import parse_row


def test_a_new_run_reopens_the_recordings_a_worker_kept_open(archive, tmp_path):
    from batch.raydata import measure_block  # imports ray.data (seconds): not at collection, which every worker pays

    rec = tmp_path / "rec"
    shutil.copytree(archive / "rec_poster", rec)
    index = rec / "frames.jsonl"
    lines = index.read_text().splitlines(keepends=True)
    assert len(lines) == 4
    index.write_text("".join(lines[:2]))  # a recording still being copied: 2 of its 4 frames
    cells = {"source": "rec", "p1_x": "100", "p1_y": "100", "p2_x": "300", "p2_y": "150"}
    block = to_block(parse_row(i, {**cells, "frame": str(i)}, tmp_path) for i in range(4))
    schema = result_schema({})
    try:
        first = measure_block(block, {}, "run-1", schema).to_pylist()
        assert [r["error"] is None for r in first] == [True, True, False, False]
        assert "frame 2 is not in" in first[2]["error"] and "2 complete frames" in first[2]["error"]
        index.write_text("".join(lines))  # the copy finished
        again = measure_block(block, {}, "run-1", schema).to_pylist()  # the same run keeps its open recording
        assert [r["error"] is None for r in again] == [True, True, False, False]
        second = measure_block(block, {}, "run-2", schema).to_pylist()
        assert [r["error"] for r in second] == [None] * 4
        assert [r["distance_m"] for r in second[:2]] == [r["distance_m"] for r in first[:2]]
        assert all(r["distance_m"] > 0 for r in second)
    finally:
        close_readers()
