"""Measurement history in SQLite (WAL), with each measured frame saved alongside as one compact file.

The database (:mod:`history.schema`) holds every :class:`measure.Measurement` field, the frame id
and clicked points, the options; the frame goes to ``<db stem>-frames/<uid>.frame``
(:mod:`history.saved_frames`, :mod:`history.frame_file`) once, however many measurements use it.

Durability, in the steps of :meth:`Store.add`: (1) write and fsync the frame file (or find it
presaved); (2) commit the row (synchronous=FULL; measurements arriving together share one commit
and its fsync); (3) answer with the record built from the values committed, without reading them
back, so nothing after the commit can fail the request. A crash between (1) and (2) leaves an
unreferenced file, deleted at the next start with any stale temporary file. A full disk raises
:class:`history.errors.StoreFull`; :meth:`Store.status` says whether the next frame would fit
(:mod:`history.space`); deletes and edits commit on a full disk through the space reserve.

Other parts: :mod:`history.checkpoint` (the WAL checkpoint thread), :mod:`history.eviction` (the
size cap ``max_bytes``), :mod:`history.cache` (encoded list records and thumbnails),
:mod:`history.export` (CSV and JSON, streamed from :meth:`Store.batches`).
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from history import schema
from history.cache import RecordCache
from history.checkpoint import Checkpointer
from history.errors import FrameDropped, FrameNotSaved, MeasurementUnknown, StoreError, StoreFull
from history.eviction import drop_over_cap
from history.export import csv_chunks
from history.frame_file import SUFFIX, encode_frame
from history.records import record, record_of_values, row_values
from history.saved_frames import SavedFrames, load_frame
from history.shape_records import shape_row_values
from history.space import Space, is_full
from measure import Frame

log = logging.getLogger(__name__)
T = TypeVar("T")
_FRAME_INSERT = schema.insert_sql("frames", schema.FRAME_INSERT, "INSERT OR IGNORE")
_MEASUREMENT_INSERT = schema.insert_sql("measurements", schema.MEASUREMENT_INSERT)
_SLIM = ", ".join(schema.SLIM_COLUMNS)
_WITH_ARRAYS = _SLIM + ", samples_px AS samples_json, support AS support_json"  # the arrays as stored, not decoded by record()

__all__ = ["Store", "StoreError", "StoreFull", "FrameDropped", "FrameNotSaved", "MeasurementUnknown", "load_frame"]


@dataclass
class _Pending:
    """A measurement waiting for the next group commit; ``finished`` (set under ``Store._lock``)
    once a commit took it, with its id or the error to raise in the requesting thread."""

    frame_row: tuple[Any, ...]
    values: tuple[Any, ...]
    finished: bool = False
    mid: int | None = None
    error: StoreError | None = None


class Store:
    """Thread-safe measurement history; ``Store(path)`` creates the database and frames folder."""

    def __init__(self, path: str | Path, *, max_bytes: int | None = None) -> None:
        self.path = Path(path)
        self.frames_dir = schema.frames_dir(self.path)
        self.max_bytes = max_bytes
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.frames_dir.mkdir(exist_ok=True)
        except OSError as exc:
            raise StoreError(f"cannot create the history folder {self.frames_dir}: {exc}; pass --db with a writable path") from exc
        self.space = Space(self.frames_dir)
        self._db = self._open()
        self._lock = threading.Lock()  # the one writing connection, self._db
        self._books = threading.Lock()  # the pending commits and the readers: never held across I/O
        self._local = threading.local()  # a reading connection per thread: reads never wait for a commit (WAL)
        self._readers: list[sqlite3.Connection] = []
        self._pending: list[_Pending] = []
        self.cache = RecordCache()
        self.frames = SavedFrames(self.frames_dir, self.space, self._is_stored)
        rows = self._db.execute("SELECT file, bytes FROM frames ORDER BY created, rowid").fetchall()
        self.space.seed([r["bytes"] for r in rows])  # right after a restart, health knows what a frame needs
        self.frames.clean_leftovers({r["file"] for r in rows})
        self.space.lay_reserve()
        self._checkpoints = Checkpointer(self.path, self._lock)

    def _open(self) -> sqlite3.Connection:
        """The writing connection; on a full disk the reserve makes room for SQLite's files."""
        for attempt in range(2):
            try:
                return schema.open_writer(self.path)
            except (OSError, sqlite3.Error) as exc:
                if attempt == 0 and is_full(exc) and self.space.release_reserve():
                    continue
                raise StoreError(f"cannot open the history database {self.path}: {exc}; pass --db with a writable path") from exc
        raise AssertionError("unreachable")

    def close(self) -> None:
        self._checkpoints.close()
        self.frames.close()
        with self._lock, self._books:
            for conn in self._readers:
                conn.close()
            self._db.close()

    def _reader(self) -> sqlite3.Connection:
        conn = getattr(self._local, "db", None)
        if conn is None:
            try:
                conn = schema.open_reader(self.path)
            except sqlite3.Error as exc:  # e.g. out of file descriptors
                raise StoreError(f"cannot read the history database {self.path}: {exc}") from exc
            self._local.db = conn
            with self._books:
                self._readers.append(conn)
        return conn

    def _one(self, sql: str, args: tuple[Any, ...] = ()) -> sqlite3.Row | None:
        return self._reader().execute(sql, args).fetchone()

    def _all(self, sql: str, args: tuple[Any, ...] = ()) -> list[sqlite3.Row]:
        return self._reader().execute(sql, args).fetchall()

    def _is_stored(self, uid: str) -> bool:
        return self._one("SELECT 1 FROM frames WHERE uid=?", (uid,)) is not None

    # -- health ----------------------------------------------------------------------------------

    def status(self, next_frame: Frame | None = None) -> dict[str, Any]:
        """``{"degraded": reason or "", "free_bytes", "need_bytes"}``: whether the next frame would be
        stored (:meth:`history.space.Space.shortage`). ``next_frame`` (the newest live frame) gives
        the size a frame needs while none of this history was saved yet (it is encoded once)."""
        if self.space.need is None and next_frame is not None:
            self.space.expect(len(encode_frame(next_frame)))
        return {"degraded": self.space.shortage(), "free_bytes": self.space.free(), "need_bytes": self.space.need}

    # -- frames ----------------------------------------------------------------------------------

    def presave(self, uid: str, frame: Frame) -> bool:
        """Start writing ``frame`` in the background (a frozen frame, about to be measured); False,
        doing nothing, while enough presaves are pending or the last write found the disk full."""
        return self.frames.presave(uid, frame, refuse=bool(self.space.failed_reason))

    def _file(self, uid: str) -> str:
        row = self._one("SELECT file FROM frames WHERE uid=?", (uid,))
        if row is None:
            raise FrameNotSaved(f"the frame {uid} of this measurement was not saved in {self.frames_dir}")
        if not row["file"]:
            raise FrameDropped(
                f"the frame {uid} of this measurement was deleted to keep the history under --history-max-gb; "
                "its numbers are kept (pin a measurement to keep its frame)"
            )
        return str(row["file"])

    def frame(self, uid: str) -> Frame:
        """The saved frame ``uid``; raises FrameNotSaved, FrameDropped or SavedFrameUnreadable."""
        return load_frame(self.frames_dir / self._file(uid))

    def preview(self, uid: str) -> tuple[np.ndarray, int]:
        """The saved colour image of frame ``uid`` decoded at 1/4 size (fast, for a thumbnail), and
        the frame's full width in px."""
        file = self._file(uid)
        row = self._one("SELECT width FROM frames WHERE uid=?", (uid,))
        return self.frames.preview(file), int(row["width"]) if row else 0

    def _after_commit(self) -> None:
        """The size cap and the presave sweep, after a measurement was stored: a failure here is
        logged, never raised, since the measurement is durable already and must be answered so."""
        try:
            if self.max_bytes is not None:
                with self._lock:
                    files = drop_over_cap(self._db, self.max_bytes)
                for file in files:
                    (self.frames_dir / file).unlink(missing_ok=True)
            self.frames.sweep()
        except (OSError, sqlite3.Error, StoreError) as exc:
            log.warning("history upkeep after a stored measurement failed (tried again at the next one): %s", exc)

    # -- measurements ----------------------------------------------------------------------------

    def add(
        self,
        *,
        frame_id: int,
        frame_uid: str,
        frame: Frame,
        source: str,
        p1: tuple[float, float],
        p2: tuple[float, float],
        options: dict[str, Any],
        result: dict[str, Any],
        thumb: bytes | None = None,
        context: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """Save the frame (once per uid), then insert one measurement (``result`` is
        ``Measurement.to_dict()``; keys beyond the known columns are kept as JSON) and return its
        stored record. ``context`` (e.g. ``frame_index`` of a replay) is kept with the result's extra
        fields. When this returns, both are durable; when it raises (StoreError), neither the row
        nor a file of its own is left."""
        return self._insert(frame_uid, frame, lambda created: row_values(
            created, frame_id, frame_uid, source, p1, p2, options, result, thumb, context))  # fmt: skip

    def add_shape(
        self,
        *,
        frame_id: int,
        frame_uid: str,
        frame: Frame,
        source: str,
        kind: str,
        points: list[tuple[float, float]],
        on: list[tuple[float, float]] | None,
        options: dict[str, Any],
        result: dict[str, Any],
        draw_px: list[tuple[float, float]],
        context: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """:meth:`add` for a shape of ``kind`` ("box", "height", "path", "area"; ``result`` its
        ``to_dict()``, ``points`` and ``on`` the clicks, ``draw_px`` what to draw, px): the same
        durability, and its record as :func:`history.shape_records.shape_record` gives it."""
        return self._insert(frame_uid, frame, lambda created: shape_row_values(
            created, frame_id, frame_uid, source, kind, points, on, options, result, draw_px, context))  # fmt: skip

    def _insert(self, frame_uid: str, frame: Frame, values_at: Callable[[float], tuple[Any, ...]]) -> dict[str, Any]:
        """Save ``frame`` as ``frame_uid`` (once per uid), commit the row ``values_at(created)`` with the
        others queued meanwhile (steps in the module docstring) and return its record."""
        with self.frames.lock(frame_uid):  # a delete of the frame's last measurement waits for this
            size = self.frames.save(frame_uid, frame)
            h, w = frame.disparity.shape
            created = time.time()
            values = values_at(created)
            frame_row = (frame_uid, f"{frame_uid}{SUFFIX}", w, h, float(frame.timestamp), str(frame.meta.get("source", "")), created, size)
            row = _Pending(frame_row, values)
            with self._books:
                self._pending.append(row)
            with self._lock:
                if not row.finished:  # no commit running took it along: commit it with all that queued meanwhile
                    with self._books:
                        batch, self._pending = self._pending, []
                    self._commit(batch)
            if row.error is not None:
                if isinstance(row.error, StoreFull) and not self._stored_quietly(frame_uid):
                    self.frames.path(frame_uid).unlink(missing_ok=True)  # give the room back
                raise row.error
            self.frames.measured(frame_uid)
        assert row.mid is not None
        answer = record_of_values(row.mid, values)  # decided now: nothing below may turn it into an error
        self._after_commit()
        return answer

    def _stored_quietly(self, uid: str) -> bool:
        try:
            return self._is_stored(uid)
        except (StoreError, sqlite3.Error):
            return True  # cannot tell: keep the file (the next start removes it if unreferenced)

    def _commit(self, batch: list[_Pending]) -> None:
        """Insert the measurements of ``batch`` (and their frames' rows) in one transaction: one
        fsync of the WAL for all requests that queued while the previous commit ran (group commit;
        the caller holds ``_lock``). A row SQLite refuses fails alone; a failed commit fails all."""
        try:
            self._db.execute("BEGIN IMMEDIATE")
            for row in batch:
                self._db.execute("SAVEPOINT one")
                try:
                    self._db.execute(_FRAME_INSERT, row.frame_row)
                    row.mid = int(self._db.execute(_MEASUREMENT_INSERT, row.values).lastrowid)
                    self._db.execute("RELEASE one")
                except sqlite3.Error as exc:
                    if is_full(exc):
                        raise
                    self._db.execute("ROLLBACK TO one")
                    self._db.execute("RELEASE one")
                    row.mid, row.error = None, StoreError(f"cannot store the measurement in {self.path}: {exc}")
            self._db.execute("COMMIT")
            self.space.wrote()
            self._checkpoints.committed(len(batch))
        except sqlite3.Error as exc:
            if self._db.in_transaction:
                self._db.execute("ROLLBACK")
            failed = self._full(exc, "measurement") if is_full(exc) else StoreError(f"cannot store the measurement in {self.path}: {exc}")
            for row in batch:
                row.mid, row.error = None, failed
        finally:
            for row in batch:
                if row.mid is None and row.error is None:  # interrupted by something other than SQLite
                    row.error = StoreError(f"the commit of the measurement to {self.path} was interrupted; measure again")
                row.finished = True

    def _full(self, exc: BaseException, what: str) -> StoreFull:
        reason = f"the disk holding {self.path} is full ({exc}); free space there or lower --history-max-gb"
        self.space.failed(reason)
        return StoreFull(f"{what} not stored: {reason}")

    def _edit(self, change: Callable[[sqlite3.Connection], T], what: str) -> T:
        """Run ``change`` on the writing connection in one transaction; on a full disk, release the
        space reserve and run it once more, so that deleting and editing work when nothing else does."""
        for attempt in range(2):
            with self._lock:
                try:
                    self._db.execute("BEGIN IMMEDIATE")
                    out = change(self._db)
                    self._db.execute("COMMIT")
                    return out
                except sqlite3.Error as exc:
                    if self._db.in_transaction:
                        self._db.execute("ROLLBACK")
                    if not is_full(exc):
                        raise StoreError(f"cannot {what} in {self.path}: {exc}") from exc
                    if attempt == 1 or not self.space.release_reserve():
                        raise self._full(exc, what) from exc
        raise AssertionError("unreachable")

    def get(self, mid: int) -> dict[str, Any] | None:
        row = self._one("SELECT * FROM measurements WHERE id=?", (mid,))
        return record(row) if row else None

    def record(self, mid: int) -> dict[str, Any]:
        """The full record of measurement ``mid``; raises :class:`MeasurementUnknown`."""
        found = self.get(mid)
        if found is None:
            raise MeasurementUnknown(f"no measurement {mid}; GET /api/measurements lists them")
        return found

    def list(self, limit: int = 1000) -> list[dict[str, Any]]:
        """Full records, newest first."""
        return [record(r) for r in self._all("SELECT * FROM measurements ORDER BY id DESC LIMIT ?", (limit,))]

    def segment(self, mid: int) -> tuple[str, list[float], list[float]]:
        """The frame uid and the clicked points (px) of measurement ``mid`` (a thumbnail's inputs),
        without decoding its record; raises :class:`MeasurementUnknown`. A shape's are its first and
        last click (:meth:`drawing` has its outline)."""
        row = self._one("SELECT frame_uid, p1_x, p1_y, p2_x, p2_y FROM measurements WHERE id=?", (mid,))
        if row is None:
            raise MeasurementUnknown(f"no measurement {mid}; GET /api/measurements lists them")
        return row["frame_uid"], [row["p1_x"], row["p1_y"]], [row["p2_x"], row["p2_y"]]

    def drawing(self, mid: int) -> tuple[str, str, list[list[float]]]:
        """The frame uid, the kind and what to draw (px) of measurement ``mid``: a segment's two
        clicks, a shape's ``draw_px``; raises :class:`MeasurementUnknown`."""
        row = self._one("SELECT frame_uid, p1_x, p1_y, p2_x, p2_y, kind, extra FROM measurements WHERE id=?", (mid,))
        if row is None:
            raise MeasurementUnknown(f"no measurement {mid}; GET /api/measurements lists them")
        ends = [[row["p1_x"], row["p1_y"]], [row["p2_x"], row["p2_y"]]]
        if row["kind"] == schema.SEGMENT:
            return row["frame_uid"], schema.SEGMENT, ends
        return row["frame_uid"], str(row["kind"]), json.loads(row["extra"] or "{}").get("shape", {}).get("draw_px") or ends

    def pin(self, mid: int, pinned: bool = True) -> dict[str, Any]:
        """Pin (or unpin) a measurement: the history cap never deletes the frame of a pinned one."""
        self.record(mid)
        self._edit(lambda db: db.execute("UPDATE measurements SET pinned=? WHERE id=?", (int(pinned), mid)), "pin the measurement")
        self.cache.changed(mid)
        return self.record(mid)

    def annotate(self, mid: int, name: str | None = None, note: str | None = None) -> dict[str, Any]:
        """Set the name and/or note of measurement ``mid`` (None leaves one as it is); its record.
        Raises :class:`MeasurementUnknown`."""

        def change(db: sqlite3.Connection) -> bool:
            row = db.execute("SELECT extra FROM measurements WHERE id=?", (mid,)).fetchone()
            if row is None:
                return False
            extra = json.loads(row["extra"] or "{}")
            extra.update({k: v for k, v in (("name", name), ("note", note)) if v is not None})
            db.execute("UPDATE measurements SET extra=? WHERE id=?", (json.dumps(extra), mid))
            return True

        if not self._edit(change, "annotate the measurement"):
            raise MeasurementUnknown(f"no measurement {mid}; GET /api/measurements lists them")
        self.cache.changed(mid)
        return self.record(mid)

    def list_slim(self, limit: int = 100, before: int | None = None, kind: str | None = None) -> list[dict[str, Any]]:
        """Records without ``samples_px`` and ``support`` (the bulk of a record), newest first,
        ``limit`` of them with an id below ``before`` (the last id of the previous page), of ``kind``
        only ("segment", "box", ...) when given."""
        return json.loads(self.list_slim_json(limit, before, kind))

    def list_slim_json(self, limit: int = 100, before: int | None = None, kind: str | None = None) -> bytes:
        """:meth:`list_slim` as JSON bytes, from the records encoded at their first listing
        (:mod:`history.cache`), so a page costs little server CPU under the GIL."""
        conditions = [("id < ?", before)] if before is not None else []
        conditions += [("kind = ?", kind)] if kind is not None else []
        where = ("WHERE " + " AND ".join(c for c, _ in conditions)) if conditions else ""
        args = (*(v for _, v in conditions), limit)
        changes = self.cache.changes
        ids = [r[0] for r in self._all(f"SELECT id FROM measurements {where} ORDER BY id DESC LIMIT ?", args)]
        parts = self.cache.slim(ids)
        missing = [i for i, p in zip(ids, parts) if p is None]
        if missing:
            fresh: dict[int, bytes] = {}
            for start in range(0, len(missing), 500):  # SQLite's bound on host parameters
                chunk = missing[start : start + 500]
                rows = self._all(f"SELECT {_SLIM} FROM measurements WHERE id IN ({','.join('?' * len(chunk))})", tuple(chunk))
                fresh |= {r["id"]: json.dumps(record(r), separators=(",", ":"), allow_nan=False).encode() for r in rows}
            self.cache.keep_slim(fresh, changes)
            parts = [p if p is not None else fresh.get(i) for i, p in zip(ids, parts)]  # None: deleted meanwhile
        return b"[" + b",".join(p for p in parts if p is not None) + b"]"

    def set_thumb(self, mid: int, thumb: bytes) -> None:
        """Keep the drawn thumbnail of ``mid`` in memory. Ids are never reused (AUTOINCREMENT), so one
        kept for a measurement deleted meanwhile is never shown: its routes find no measurement first."""
        self.cache.keep_thumb(mid, thumb)

    def thumb(self, mid: int) -> bytes | None:
        """The thumbnail drawn for ``mid`` (or kept in the database by earlier versions), or None."""
        data = self.cache.thumb(mid)
        if data is not None:
            return data
        row = self._one("SELECT thumb FROM measurements WHERE id=?", (mid,))
        return bytes(row["thumb"]) if row and row["thumb"] is not None else None

    def delete(self, mid: int) -> None:
        """Delete a measurement; its saved frame goes too once no measurement refers to it (the file
        after the commit, so a failed delete leaves everything as it was). Raises MeasurementUnknown."""
        uid = self.segment(mid)[0]

        def change(db: sqlite3.Connection) -> tuple[bool, str | None]:
            if not db.execute("DELETE FROM measurements WHERE id=?", (mid,)).rowcount:
                return False, None
            if db.execute("SELECT 1 FROM measurements WHERE frame_uid=? LIMIT 1", (uid,)).fetchone():
                return True, None
            frow = db.execute("SELECT file FROM frames WHERE uid=?", (uid,)).fetchone()
            db.execute("DELETE FROM frames WHERE uid=?", (uid,))
            return True, frow["file"] if frow else None

        with self.frames.lock(uid):
            deleted, file = self._edit(change, "delete the measurement")
            if not deleted:
                raise MeasurementUnknown(f"no measurement {mid}; GET /api/measurements lists them")
            self.cache.changed(mid)
            if file:
                (self.frames_dir / file).unlink(missing_ok=True)
        self.space.lay_reserve()

    def batches(self, size: int = 500, *, arrays: bool = False) -> Iterator[list[sqlite3.Row]]:
        """Every measurement's row, oldest first, ``size`` rows a batch: the slim columns (what
        :func:`history.records.record` reads), with ``arrays`` also ``samples_json`` and
        ``support_json`` (the per-sample arrays' stored JSON text). Each batch is one query on the
        reading connection of the thread that asks for it, so a streamed response may pull batches
        from any worker thread; measurements stored after the first batch are not included."""
        columns = _WITH_ARRAYS if arrays else _SLIM
        newest = self._one("SELECT MAX(id) AS id FROM measurements")
        last, top = 0, (newest["id"] if newest else None) or 0
        while last < top:
            rows = self._all(f"SELECT {columns} FROM measurements WHERE id > ? AND id <= ? ORDER BY id LIMIT ?", (last, top, size))
            if not rows:
                return
            last = rows[-1]["id"]
            yield rows

    def csv(self, units: str = "m", base_url: str = "") -> str:
        """All measurements as CSV (oldest first): :func:`history.export.csv_chunks` as one text."""
        return "".join(csv_chunks(self.batches(), units, base_url))
