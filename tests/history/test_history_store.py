"""The history package on its own: the read-only reader's checks, and edits on a full disk through
the space reserve."""

from __future__ import annotations

import sqlite3

import pytest
from factories import wall_frame

from history import schema
from history.errors import HistoryUnreadable, StoreFull
from history.space import RESERVE_BYTES
from history.store import Store

RESULT = {
    "distance_m": 1.0, "method": "basic", "fit": "none", "p1_m": [0, 0, 2], "p2_m": [1, 0, 2], "basic_distance_m": 1.0,
    "uncertainty_m": 0.01, "n_samples": 3, "n_valid": 3, "n_support": 3, "samples_px": [[1, 1]], "support": [True],
    "gap_detected": False, "warnings": [], "elapsed_ms": 1,
}  # fmt: skip


def test_read_only_reader_names_what_is_wrong(tmp_path):
    with pytest.raises(HistoryUnreadable, match="does not exist"):
        schema.open_read_only(tmp_path / "none.db")
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE measurements (id INTEGER)")
    with pytest.raises(HistoryUnreadable, match="not a depthruler history database"):
        schema.open_read_only(other)
    store = Store(tmp_path / "h.db")
    rec = store.add(frame_id=3, frame_uid="u", frame=wall_frame(0), source="s", p1=(1, 2), p2=(3, 4), options={"window": 7}, result=RESULT)
    store.close()
    con = schema.open_read_only(tmp_path / "h.db")
    (row,) = schema.measurement_inputs(con)
    con.close()
    assert (row["id"], row["frame_uid"], row["p1_x"], row["p2_y"], row["options"], row["file"]) == (rec["id"], "u", 1.0, 4.0, '{"window": 7}', "u.frame")
    assert (schema.frames_dir(tmp_path / "h.db") / row["file"]).is_file()


class _FullOnce:
    """The store's writing connection, refusing the first UPDATE or DELETE as SQLite does on a full disk."""

    def __init__(self, db: sqlite3.Connection, times: int = 1) -> None:
        self._db, self.left = db, times

    def execute(self, sql: str, *args):
        if self.left and sql.split()[0] in ("UPDATE", "DELETE"):
            self.left -= 1
            raise sqlite3.OperationalError("database or disk is full")
        return self._db.execute(sql, *args)

    def __getattr__(self, name):
        return getattr(self._db, name)


def test_edits_on_a_full_disk_release_the_reserve_and_commit(tmp_path):
    store = Store(tmp_path / "h.db")
    try:
        mid = store.add(frame_id=1, frame_uid="u", frame=wall_frame(0), source="s", p1=(1, 2), p2=(3, 4), options={}, result=RESULT)["id"]
        assert store.space.reserve.stat().st_size == RESERVE_BYTES
        real = store._db
        store._db = _FullOnce(real)
        assert store.annotate(mid, name="door")["name"] == "door"  # committed on the second try
        assert not store.space.reserve.exists()  # the room it took
        store._db = _FullOnce(real, times=2)  # no reserve left, and still full: the edit fails whole
        with pytest.raises(StoreFull, match="full"):
            store.pin(mid)
        assert store.get(mid)["pinned"] is False
        store._db = real
        store.delete(mid)
        assert store.get(mid) is None and not (store.frames_dir / "u.frame").exists()
        assert store.space.reserve.exists()  # laid again once there was room
    finally:
        store._db = real
        store.close()
