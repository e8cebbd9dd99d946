"""Measurement history in SQLite (WAL), with each measured frame saved alongside as one compact file.

The database holds every :class:`measure.Measurement` field, the frame id and clicked points,
the options (thumbnails only from earlier versions). The frame itself goes to
``<db stem>-frames/<uid>.frame`` (:mod:`history.frame_file`: PNG16 disparity, JPEG colour,
camera) once, however many measurements use it, so history survives a restart and a
measurement can be re-opened and re-measured on its frame.

Durability: :meth:`Store.add` writes and fsyncs the frame file *before* it commits the row
(synchronous=FULL; measurements arriving together share one commit and its fsync), so a
measurement that was answered is on disk with its frame, whatever happens next (SIGKILL, power).
A crash between the two leaves an unreferenced file, deleted at the next start with any stale
temporary file. A full disk raises :class:`StoreFull` (HTTP 507) and marks the store degraded
until a probe write succeeds again.

Speed: :meth:`Store.presave` (called when a frame is frozen, before anyone clicks on it) writes
the frame on one of two background threads, so the measurement that follows (a person's click,
100 ms or more later) usually finds it on disk and only commits its row. A measurement never
waits behind other frames: when its frame's presave has not started yet, it writes the frame
itself (the presave then finds it saved); beyond ``_PRESAVE_PENDING`` queued frames (8 clients
each freezing a frame) presaves are skipped.
Thumbnails are drawn on first request, not on the measuring path, and kept in memory (they are
derived data: a commit, with its fsync and the write lock, per thumbnail would make measurements
wait). The history list is served from slim records encoded once per measurement and kept until
the measurement changes (name, note, pin, delete): the page reads the list after every click.

Size: with ``max_bytes`` the frame files are capped; beyond it the oldest frames that no pinned
measurement uses are deleted (their measurements stay, without a frame to reopen).
"""

from __future__ import annotations

import csv
import errno
import io
import json
import math
import sqlite3
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from history.frame_file import SUFFIX, TMP_SUFFIX, encode_frame, load_frame_file, write_durably
from measure import Frame

_SCHEMA = """
CREATE TABLE IF NOT EXISTS frames (
    uid TEXT PRIMARY KEY,
    file TEXT NOT NULL,
    width INTEGER NOT NULL,
    height INTEGER NOT NULL,
    timestamp REAL NOT NULL,
    source TEXT NOT NULL,
    created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS measurements (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    created REAL NOT NULL,
    frame_id INTEGER NOT NULL,
    frame_uid TEXT NOT NULL REFERENCES frames(uid),
    source TEXT NOT NULL,
    p1_x REAL NOT NULL, p1_y REAL NOT NULL, p2_x REAL NOT NULL, p2_y REAL NOT NULL,
    options TEXT NOT NULL,
    distance_m REAL,
    method TEXT NOT NULL,
    fit TEXT NOT NULL,
    p1_m TEXT NOT NULL,
    p2_m TEXT NOT NULL,
    basic_distance_m REAL,
    uncertainty_m REAL,
    n_samples INTEGER NOT NULL,
    n_valid INTEGER NOT NULL,
    n_support INTEGER NOT NULL,
    samples_px TEXT NOT NULL,
    support TEXT NOT NULL,
    gap_detected INTEGER NOT NULL,
    warnings TEXT NOT NULL,
    elapsed_ms REAL NOT NULL,
    thumb BLOB
);
"""
_MIGRATIONS = (  # columns added since the first schema: (table, column, declaration)
    ("frames", "bytes", "INTEGER NOT NULL DEFAULT 0"),
    ("measurements", "pinned", "INTEGER NOT NULL DEFAULT 0"),
    ("measurements", "extra", "TEXT NOT NULL DEFAULT '{}'"),
)
_FIXED_RESULT_KEYS = frozenset(
    ("distance_m", "method", "fit", "p1_m", "p2_m", "basic_distance_m", "uncertainty_m", "n_samples", "n_valid",
     "n_support", "samples_px", "support", "gap_detected", "warnings", "elapsed_ms")
)  # fmt: skip
_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
_PROBE_INTERVAL_S = 0.5
_PRESAVE_WORKERS = 2  # the encoding (~17 ms CPU at 720p) runs in OpenCV, outside the GIL: one per core
_PRESAVE_PENDING = 8  # presaves queued or running at most
_CHECKPOINT_QUIET_S = 1.0  # a WAL checkpoint (on its own thread) waits for this long without a commit...
_CHECKPOINT_ROWS = 100  # ...or for this many rows committed since the last one (~7 WAL pages a measurement)
_WAL_RESTART_PAGES = 1000  # SQLite's own checkpoint threshold: beyond it, finish a pass under the write lock
_PRESAVE_KEEP_S = 600.0  # a presaved frame nobody measured within this is deleted
_SLIM_CACHE = 10_000  # encoded slim records kept (~1 KB each): the largest page of the history list
_THUMB_CACHE = 512  # drawn thumbnails kept in memory (~6 KB each); drawing one again takes ~2 ms
_SLIM_COLUMNS = (
    "id, created, frame_id, frame_uid, source, p1_x, p1_y, p2_x, p2_y, options, distance_m, method, fit, p1_m, p2_m, "
    "basic_distance_m, uncertainty_m, n_samples, n_valid, n_support, gap_detected, warnings, elapsed_ms, pinned, extra"
)  # every column but the per-sample arrays and the thumbnail

UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0, "in": 1 / 0.0254}

CSV_COLUMNS = (
    "id", "created_utc", "name", "note", "source", "frame_id", "frame_index", "units", "distance", "uncertainty_1sigma",
    "interval_low", "interval_high", "quality", "reasons", "method", "fit", "basic_distance",
    "p1_x_px", "p1_y_px", "p2_x_px", "p2_y_px", "p1_X", "p1_Y", "p1_Z", "p2_X", "p2_Y", "p2_Z",
    "n_samples", "n_valid", "n_support", "gap_detected", "warnings", "frame_url",
)  # fmt: skip
"""Lengths and 3D coordinates are in ``units``, rounded to what the measurement supports
(:func:`supported_decimals`); pixels to 0.1 px. ``frame_url`` opens the saved colour image."""


def supported_decimals(sigma: float | None, factor: float) -> int:
    """Decimals that keep two significant digits of the 1-sigma uncertainty ``sigma`` (m) in a unit of
    ``factor`` per metre: more would be noise, fewer would hide the precision. 4 when unknown."""
    if sigma is None or not math.isfinite(sigma) or sigma <= 0:
        return 4
    return int(min(6, max(0, 1 - math.floor(math.log10(sigma * factor)))))


class StoreError(RuntimeError):
    """The history database or a saved frame cannot be read or written; names the file."""


class StoreFull(StoreError):
    """The disk holding the history is full (HTTP 507)."""


class FrameDropped(StoreError):
    """The measurement's frame was deleted by the history cap (HTTP 410)."""


def load_frame(path: Path) -> Frame:
    """Read a saved frame: a ``.frame`` file, or an ``.npz`` of earlier versions."""
    try:
        return load_frame_file(path)
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise StoreError(f"cannot read saved frame {path}: {exc}; the history entry needs this file") from exc
    except Exception as exc:  # zipfile.BadZipFile and friends: a damaged file, never a crash
        raise StoreError(f"cannot read saved frame {path}: {exc}; the file is damaged") from exc


def _num(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _is_full(exc: BaseException) -> bool:
    if isinstance(exc, OSError):
        return exc.errno in _FULL_ERRNOS
    return isinstance(exc, sqlite3.Error) and (
        getattr(exc, "sqlite_errorcode", None) == 13 or "full" in str(exc).lower()  # SQLITE_FULL
    )


@dataclass
class _Pending:
    """A measurement waiting for the next group commit; ``finished`` (set under ``Store._lock``)
    once a commit took it, with its id or the error to raise in the requesting thread."""

    frame_row: tuple[Any, ...]
    values: tuple[Any, ...]
    finished: bool = False
    mid: int | None = None
    error: tuple[type[StoreError], str] | None = None


class Store:
    """Thread-safe measurement history; ``Store(path)`` creates the database and frames folder."""

    def __init__(self, path: str | Path, *, max_bytes: int | None = None) -> None:
        self.path = Path(path)
        self.frames_dir = self.path.with_name(self.path.stem + "-frames")
        self.max_bytes = max_bytes
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.frames_dir.mkdir(exist_ok=True)
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")  # a committed row survives power loss, not only a crash
            # Checkpoints run on their own thread (_checkpoints), not inside a measurement's commit:
            # one every ~1000 pages (~140 measurements) took 50-350 ms there, and the group behind it waited.
            self._db.execute("PRAGMA wal_autocheckpoint=0")
            self._db.executescript(_SCHEMA)
            for table, column, decl in _MIGRATIONS:
                if column not in {r[1] for r in self._db.execute(f"PRAGMA table_info({table})")}:
                    self._db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"cannot open the history database {self.path}: {exc}; pass --db with a writable path") from exc
        self._db.row_factory = sqlite3.Row
        self._lock = threading.Lock()  # the one writing connection, self._db
        self._books = threading.Lock()  # bookkeeping (uid locks, presaves, readers): never held across I/O
        self._local = threading.local()  # a reading connection per thread: reads never wait for a commit (WAL)
        self._readers: list[sqlite3.Connection] = []
        self._saving: dict[str, threading.Lock] = {}  # one writer per frame uid; other frames go side by side
        self._degraded = ""
        self._next_probe = 0.0
        self._presaver = ThreadPoolExecutor(max_workers=_PRESAVE_WORKERS, thread_name_prefix="depthruler-presave")
        self._presaving = 0
        self._presaved: dict[str, float] = {}  # uid -> when, for frames saved before any measurement
        self._pending: list[_Pending] = []  # measurements for the next group commit (under _books)
        self._slim: dict[int, bytes] = {}  # id -> JSON of its slim record (under _books)
        self._changes = 0  # bumped (under _books) whenever a stored record changes: stale encodings are not cached
        self._thumbs: OrderedDict[int, bytes] = OrderedDict()  # id -> thumbnail, least recently used first
        self._clean_leftovers()
        self._closing = threading.Event()
        self._uncopied = 0  # rows committed since the last checkpoint (under _books)
        self._last_commit = time.monotonic()
        self._checkpointer = threading.Thread(target=self._checkpoints, name="depthruler-checkpoint", daemon=True)
        self._checkpointer.start()

    def close(self) -> None:
        self._closing.set()
        self._checkpointer.join()
        self._presaver.shutdown(wait=True)
        with self._lock, self._books:
            for conn in self._readers:
                conn.close()
            self._db.close()

    def _checkpoints(self) -> None:
        """Copy the WAL's committed pages into the database beside the commits, when the store has
        been quiet for ``_CHECKPOINT_QUIET_S`` or ``_CHECKPOINT_ROWS`` rows wait (a checkpoint's
        fsync of the database slows a commit's fsync running at the same time: one per second under
        steady clicking cost the p95 ~10 ms). PASSIVE: it never waits for a writer or a reader; past
        ``_WAL_RESTART_PAGES`` it finishes under the write lock so the WAL can start over. The rows
        are durable already (the WAL is fsynced at each commit)."""
        conn = sqlite3.connect(self.path, isolation_level=None)
        try:
            conn.execute("PRAGMA synchronous=FULL")
            while not self._closing.wait(min(0.25, _CHECKPOINT_QUIET_S)):
                with self._books:
                    due = self._uncopied >= _CHECKPOINT_ROWS or (
                        self._uncopied > 0 and time.monotonic() - self._last_commit >= _CHECKPOINT_QUIET_S
                    )
                    if due:
                        self._uncopied = 0  # rows committed from now on count toward the next pass
                if not due:
                    continue
                try:
                    _, wal_pages, copied = conn.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
                    if wal_pages > _WAL_RESTART_PAGES and copied < wal_pages:
                        # Commits kept coming during the pass, so the WAL never starts over and grows:
                        # copy the few pages left while no commit runs.
                        with self._lock:
                            conn.execute("PRAGMA wal_checkpoint(PASSIVE)")
                except sqlite3.Error:
                    with self._books:
                        self._uncopied += 1  # a full disk or a busy database: try again later
        finally:
            conn.close()

    def _reader(self) -> sqlite3.Connection:
        conn = getattr(self._local, "db", None)
        if conn is None:
            conn = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            conn.row_factory = sqlite3.Row
            conn.execute("PRAGMA query_only=1")
            self._local.db = conn
            with self._books:
                self._readers.append(conn)
        return conn

    def _one(self, sql: str, args: tuple[Any, ...] = ()) -> sqlite3.Row | None:
        return self._reader().execute(sql, args).fetchone()

    def _all(self, sql: str, args: tuple[Any, ...] = ()) -> list[sqlite3.Row]:
        return self._reader().execute(sql, args).fetchall()

    def _clean_leftovers(self) -> None:
        """Delete what a crash can leave: temporary files, and frame files whose row was never committed."""
        with self._lock:
            known = {r["file"] for r in self._db.execute("SELECT file FROM frames")}
        for p in self.frames_dir.iterdir():
            stale = p.name.endswith((TMP_SUFFIX, ".tmp.npz"))
            orphan = p.suffix in (SUFFIX, ".npz") and p.name not in known
            if (stale or orphan) and p.is_file():
                p.unlink(missing_ok=True)

    # -- health ----------------------------------------------------------------------------------

    def _full(self, exc: BaseException, what: str) -> StoreFull:
        self._degraded = f"the disk holding {self.frames_dir} is full ({exc}); free space there or lower --history-max-gb"
        self._next_probe = 0.0
        return StoreFull(f"{what} not stored: {self._degraded}")

    @property
    def degraded(self) -> str:
        return self._degraded

    def status(self) -> dict[str, Any]:
        """``{"degraded": reason or "", ...}``; while degraded, a probe write (at most twice a
        second) checks whether space came back, and clears the state when it did."""
        if self._degraded and time.monotonic() >= self._next_probe:
            self._next_probe = time.monotonic() + _PROBE_INTERVAL_S
            probe = self.frames_dir / f".probe{TMP_SUFFIX}"
            try:
                write_durably(probe, b"\0" * 65536)
                probe.unlink()
                with self._lock:
                    self._db.execute("PRAGMA wal_checkpoint(PASSIVE)")
                self._degraded = ""
            except (OSError, sqlite3.Error):
                probe.unlink(missing_ok=True)
        return {"degraded": self._degraded}

    # -- frames ----------------------------------------------------------------------------------

    @contextmanager
    def _frame_lock(self, uid: str) -> Iterator[None]:
        with self._books:
            lock = self._saving.setdefault(uid, threading.Lock())
        with lock:
            yield
        with self._books:
            if self._saving.get(uid) is lock and not lock.locked():
                del self._saving[uid]

    def presave(self, uid: str, frame: Frame) -> bool:
        """Start writing ``frame`` in the background (a frozen frame, about to be measured); returns
        False, doing nothing, while ``_PRESAVE_PENDING`` presaves are queued or running, or the disk is full."""
        with self._books:
            if self._presaving >= _PRESAVE_PENDING or self._degraded:
                return False
            self._presaving += 1
        self._presaver.submit(self._presave, uid, frame)
        return True

    def _presave(self, uid: str, frame: Frame) -> None:
        try:
            with self._frame_lock(uid):
                known = self._one("SELECT 1 FROM frames WHERE uid=?", (uid,))
                if not known and not (self.frames_dir / f"{uid}{SUFFIX}").exists():
                    self._save_frame(uid, frame)
                    with self._books:
                        self._presaved[uid] = time.monotonic()
        except StoreError:
            pass  # the measurement, if one comes, writes the frame itself and reports the error
        finally:
            with self._books:
                self._presaving -= 1

    def _sweep_presaved(self) -> None:
        """Delete presaved frames that no measurement used within ``_PRESAVE_KEEP_S``."""
        now = time.monotonic()
        with self._books:
            old = [u for u, t in self._presaved.items() if now - t > _PRESAVE_KEEP_S]
        for uid in old:
            with self._frame_lock(uid):
                with self._books:
                    self._presaved.pop(uid, None)
                used = self._one("SELECT 1 FROM frames WHERE uid=?", (uid,))
                if not used:
                    (self.frames_dir / f"{uid}{SUFFIX}").unlink(missing_ok=True)

    def _save_frame(self, uid: str, frame: Frame) -> int:
        """Write ``frame`` as ``<uid>.frame`` durably unless it is there already (the caller holds
        the uid's lock); returns its size. Raises StoreFull on a full disk, StoreError otherwise."""
        path = self.frames_dir / f"{uid}{SUFFIX}"
        if path.exists():  # the rename is atomic: a file under this name is complete
            return path.stat().st_size
        data = encode_frame(frame)
        try:
            write_durably(path, data)
        except OSError as exc:
            if _is_full(exc):
                raise self._full(exc, f"frame {uid}") from None
            raise StoreError(f"cannot save frame {uid} to {path}: {exc}") from exc
        return len(data)

    def frame(self, uid: str) -> Frame:
        row = self._one("SELECT file FROM frames WHERE uid=?", (uid,))
        if row is None:
            raise StoreError(f"the frame {uid} of this measurement was not saved in {self.frames_dir}")
        if not row["file"]:
            raise FrameDropped(
                f"the frame {uid} of this measurement was deleted to keep the history under --history-max-gb; "
                "its numbers are kept (pin a measurement to keep its frame)"
            )
        return load_frame(self.frames_dir / row["file"])

    def preview(self, uid: str) -> tuple[np.ndarray, int]:
        """The saved colour image of frame ``uid`` decoded at 1/4 size (fast, for a thumbnail), and
        the frame's full width."""
        row = self._one("SELECT file, width FROM frames WHERE uid=?", (uid,))
        if row is None or not row["file"]:
            raise StoreError(f"the frame {uid} is not saved (any more)")
        path = self.frames_dir / row["file"]
        if path.suffix == ".npz":
            return load_frame(path).image, row["width"]
        try:
            import zipfile

            with zipfile.ZipFile(path) as zf:
                data = zf.read("color.jpg")
        except Exception as exc:  # noqa: BLE001 — a damaged file is a missing thumbnail, not a crash
            raise StoreError(f"cannot read saved frame {path}: {exc}") from exc
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_REDUCED_COLOR_4)
        if image is None:
            raise StoreError(f"the colour image in {path} cannot be decoded")
        return image, row["width"]

    def _enforce_cap(self) -> None:
        """Delete the oldest frames no pinned measurement uses until the files fit ``max_bytes``
        (the newest frame always stays)."""
        if self.max_bytes is None:
            return
        with self._lock:
            total = self._db.execute("SELECT COALESCE(SUM(bytes), 0) FROM frames WHERE file != ''").fetchone()[0]
            if total <= self.max_bytes:
                return
            rows = self._db.execute(
                "SELECT uid, file, bytes FROM frames WHERE file != '' AND uid NOT IN "
                "(SELECT frame_uid FROM measurements WHERE pinned=1) ORDER BY created, rowid"
            ).fetchall()[:-1]
            victims = []
            for r in rows:
                if total <= self.max_bytes:
                    break
                victims.append(r)
                total -= r["bytes"]
            self._db.executemany("UPDATE frames SET file='' WHERE uid=?", [(r["uid"],) for r in victims])
        for r in victims:
            (self.frames_dir / r["file"]).unlink(missing_ok=True)

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
        fields. When this returns, both are durable."""
        with self._frame_lock(frame_uid):  # a delete of the frame's last measurement waits for this
            mid = self._add(frame_uid, frame, frame_id, source, p1, p2, options, result, thumb, context)
        self._enforce_cap()
        self._sweep_presaved()
        record = self.get(mid)
        assert record is not None
        return record

    def _add(
        self, frame_uid: str, frame: Frame, frame_id: int, source: str, p1: tuple[float, float], p2: tuple[float, float],
        options: dict[str, Any], result: dict[str, Any], thumb: bytes | None, context: dict[str, Any] | None,
    ) -> int:  # fmt: skip
        size = self._save_frame(frame_uid, frame)
        h, w = frame.disparity.shape
        created = time.time()
        extra = {k: v for k, v in result.items() if k not in _FIXED_RESULT_KEYS} | (context or {})
        values = (
            created, frame_id, frame_uid, source, float(p1[0]), float(p1[1]), float(p2[0]), float(p2[1]),
            json.dumps(options), result["distance_m"], result["method"], result["fit"], json.dumps(result["p1_m"]),
            json.dumps(result["p2_m"]), result["basic_distance_m"], result["uncertainty_m"], result["n_samples"],
            result["n_valid"], result["n_support"], json.dumps(result["samples_px"]), json.dumps(result["support"]),
            int(result["gap_detected"]), json.dumps(result["warnings"]), result["elapsed_ms"], thumb, json.dumps(extra),
        )  # fmt: skip
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
            kind, message = row.error
            raise kind(message)
        with self._books:
            self._presaved.pop(frame_uid, None)
        assert row.mid is not None
        return row.mid

    def _commit(self, batch: list[_Pending]) -> None:
        """Insert the measurements of ``batch`` (and their frames' rows) in one transaction: one
        fsync of the WAL for all requests that queued while the previous commit ran (group commit;
        the caller holds ``_lock``). A row SQLite refuses fails alone; a failed commit fails all."""
        try:
            self._db.execute("BEGIN IMMEDIATE")
            for row in batch:
                self._db.execute("SAVEPOINT one")
                try:
                    self._db.execute(
                        "INSERT OR IGNORE INTO frames(uid, file, width, height, timestamp, source, created, bytes) "
                        "VALUES (?,?,?,?,?,?,?,?)",
                        row.frame_row,
                    )
                    cur = self._db.execute(
                        "INSERT INTO measurements(created, frame_id, frame_uid, source, p1_x, p1_y, p2_x, p2_y, options, "
                        "distance_m, method, fit, p1_m, p2_m, basic_distance_m, uncertainty_m, n_samples, n_valid, "
                        "n_support, samples_px, support, gap_detected, warnings, elapsed_ms, thumb, extra) "
                        "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                        row.values,
                    )
                    row.mid = int(cur.lastrowid)
                    self._db.execute("RELEASE one")
                except sqlite3.Error as exc:
                    if _is_full(exc):
                        raise
                    self._db.execute("ROLLBACK TO one")
                    self._db.execute("RELEASE one")
                    row.error = (StoreError, f"cannot store the measurement in {self.path}: {exc}")
            self._db.execute("COMMIT")
            self._degraded = ""  # a write went through: space is back
            with self._books:
                self._uncopied += len(batch)
                self._last_commit = time.monotonic()
        except sqlite3.Error as exc:
            if self._db.in_transaction:
                self._db.execute("ROLLBACK")
            failed = self._full(exc, "measurement") if _is_full(exc) else StoreError(f"cannot store the measurement in {self.path}: {exc}")
            for row in batch:
                row.mid, row.error = None, (type(failed), str(failed))
        finally:
            for row in batch:
                if row.mid is None and row.error is None:  # interrupted by something other than SQLite
                    row.error = (StoreError, f"the commit of the measurement to {self.path} was interrupted; measure again")
                row.finished = True

    def pin(self, mid: int, pinned: bool = True) -> dict[str, Any] | None:
        """Pin (or unpin) a measurement: the history cap never deletes the frame of a pinned one."""
        with self._lock:
            self._db.execute("UPDATE measurements SET pinned=? WHERE id=?", (int(pinned), mid))
        self._changed(mid)
        return self.get(mid)

    @staticmethod
    def _record(row: sqlite3.Row) -> dict[str, Any]:
        keys = row.keys()
        extra = json.loads(row["extra"] or "{}")
        return {
            **extra,  # newer Measurement fields (quality, reasons, ...) and frame_index; never shadow ours
            "name": str(extra.get("name", "")),
            "note": str(extra.get("note", "")),
            "id": row["id"],
            "created": row["created"],
            "frame_id": row["frame_id"],
            "frame_uid": row["frame_uid"],
            "source": row["source"],
            "p1": [row["p1_x"], row["p1_y"]],
            "p2": [row["p2_x"], row["p2_y"]],
            "options": json.loads(row["options"]),
            "distance_m": _num(row["distance_m"]),
            "method": row["method"],
            "fit": row["fit"],
            "p1_m": json.loads(row["p1_m"]),
            "p2_m": json.loads(row["p2_m"]),
            "basic_distance_m": _num(row["basic_distance_m"]),
            "uncertainty_m": _num(row["uncertainty_m"]),
            "n_samples": row["n_samples"],
            "n_valid": row["n_valid"],
            "n_support": row["n_support"],
            **({"samples_px": json.loads(row["samples_px"]), "support": json.loads(row["support"])} if "support" in keys else {}),
            "gap_detected": bool(row["gap_detected"]),
            "warnings": json.loads(row["warnings"]),
            "elapsed_ms": row["elapsed_ms"],
            "pinned": bool(row["pinned"]),
        }

    def segment(self, mid: int) -> tuple[str, list[float], list[float]] | None:
        """The frame uid and the clicked points (px) of measurement ``mid`` (a thumbnail's inputs),
        without decoding its record; None when there is no such measurement."""
        row = self._one("SELECT frame_uid, p1_x, p1_y, p2_x, p2_y FROM measurements WHERE id=?", (mid,))
        return None if row is None else (row["frame_uid"], [row["p1_x"], row["p1_y"]], [row["p2_x"], row["p2_y"]])

    def get(self, mid: int) -> dict[str, Any] | None:
        row = self._one("SELECT * FROM measurements WHERE id=?", (mid,))
        return self._record(row) if row else None

    def list(self, limit: int = 1000) -> list[dict[str, Any]]:
        """Full records, newest first."""
        rows = self._all("SELECT * FROM measurements ORDER BY id DESC LIMIT ?", (limit,))
        return [self._record(r) for r in rows]

    def annotate(self, mid: int, name: str | None = None, note: str | None = None) -> dict[str, Any] | None:
        """Set the name and/or note of measurement ``mid`` (None leaves one as it is); its record, or
        None when there is no such measurement."""
        with self._lock:
            row = self._db.execute("SELECT extra FROM measurements WHERE id=?", (mid,)).fetchone()
            if row is None:
                return None
            extra = json.loads(row["extra"] or "{}")
            extra.update({k: v for k, v in (("name", name), ("note", note)) if v is not None})
            self._db.execute("UPDATE measurements SET extra=? WHERE id=?", (json.dumps(extra), mid))
        self._changed(mid)
        return self.get(mid)

    def list_slim(self, limit: int = 100, before: int | None = None) -> list[dict[str, Any]]:
        """Records without ``samples_px`` and ``support`` (the bulk of a record), newest first,
        ``limit`` of them with an id below ``before`` (the last id of the previous page)."""
        return json.loads(self.list_slim_json(limit, before))

    def list_slim_json(self, limit: int = 100, before: int | None = None) -> bytes:
        """:meth:`list_slim` as JSON bytes, from the records encoded at their first listing: a page
        of 100 costs ~0.5 ms of server CPU a request instead of ~5 ms of decoding and encoding under the GIL."""
        where, args = ("WHERE id < ?", (before, limit)) if before is not None else ("", (limit,))
        with self._books:
            changes = self._changes
        ids = [r[0] for r in self._all(f"SELECT id FROM measurements {where} ORDER BY id DESC LIMIT ?", args)]
        with self._books:
            parts = [self._slim.get(i) for i in ids]
        missing = [i for i, p in zip(ids, parts) if p is None]
        if missing:
            fresh: dict[int, bytes] = {}
            for start in range(0, len(missing), 500):  # SQLite's bound on host parameters
                chunk = missing[start : start + 500]
                rows = self._all(f"SELECT {_SLIM_COLUMNS} FROM measurements WHERE id IN ({','.join('?' * len(chunk))})", tuple(chunk))
                fresh |= {r["id"]: json.dumps(self._record(r), separators=(",", ":"), allow_nan=False).encode() for r in rows}
            with self._books:
                if self._changes == changes:  # nothing changed since the ids were read: the encodings are current
                    self._slim |= fresh
                    for old in list(self._slim)[: max(0, len(self._slim) - _SLIM_CACHE)]:
                        del self._slim[old]
            parts = [p if p is not None else fresh.get(i) for i, p in zip(ids, parts)]  # None: deleted meanwhile
        return b"[" + b",".join(p for p in parts if p is not None) + b"]"

    def _changed(self, mid: int) -> None:
        """Measurement ``mid`` was changed or deleted (after the write): drop what was derived from it."""
        with self._books:
            self._changes += 1
            self._slim.pop(mid, None)
            self._thumbs.pop(mid, None)

    def set_thumb(self, mid: int, thumb: bytes) -> None:
        """Keep the drawn thumbnail of ``mid`` in memory (the least recently used go beyond
        ``_THUMB_CACHE``). Ids are never reused (AUTOINCREMENT), so one kept for a measurement
        deleted meanwhile is never shown: its routes answer 404 first."""
        with self._books:
            self._thumbs[mid] = thumb
            while len(self._thumbs) > _THUMB_CACHE:
                self._thumbs.popitem(last=False)

    def thumb(self, mid: int) -> bytes | None:
        """The thumbnail drawn for ``mid`` (or kept in the database by earlier versions), or None."""
        with self._books:
            data = self._thumbs.get(mid)
            if data is not None:
                self._thumbs.move_to_end(mid)
                return data
        row = self._one("SELECT thumb FROM measurements WHERE id=?", (mid,))
        return bytes(row["thumb"]) if row and row["thumb"] is not None else None

    def delete(self, mid: int) -> bool:
        """Delete a measurement; its saved frame goes too once no measurement refers to it."""
        row = self._one("SELECT frame_uid FROM measurements WHERE id=?", (mid,))
        if row is None:
            return False
        with self._frame_lock(row["frame_uid"]):
            return self._delete(mid, row["frame_uid"])

    def _delete(self, mid: int, uid: str) -> bool:
        with self._lock:
            if not self._db.execute("DELETE FROM measurements WHERE id=?", (mid,)).rowcount:
                return False
            self._changed(mid)
            orphan = not self._db.execute("SELECT 1 FROM measurements WHERE frame_uid=? LIMIT 1", (uid,)).fetchone()
            file = None
            if orphan:
                frow = self._db.execute("SELECT file FROM frames WHERE uid=?", (uid,)).fetchone()
                self._db.execute("DELETE FROM frames WHERE uid=?", (uid,))
                file = frow["file"] if frow else None
        if file:
            (self.frames_dir / file).unlink(missing_ok=True)
        return True

    def csv(self, units: str = "m", base_url: str = "") -> str:
        """All measurements as CSV (oldest first), columns :data:`CSV_COLUMNS`; lengths in ``units``
        rounded to what each measurement supports; ``frame_url`` is ``base_url`` + the route of its frame."""
        k = UNITS[units]
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        for r in reversed(self.list(limit=1_000_000)):
            dec = supported_decimals(r["uncertainty_m"], k)

            def length(v: Any, dec: int = dec) -> str:
                return "" if v is None else f"{float(v) * k:.{dec}f}"

            sigma = "" if r["uncertainty_m"] is None else f"{r['uncertainty_m'] * k:.2g}"
            lo, hi = (list(r.get("interval_m") or []) + [None, None])[:2]
            created = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(r["created"]))
            writer.writerow(
                [r["id"], created, r["name"], r["note"], r["source"], r["frame_id"], r.get("frame_index", ""), units,
                 length(r["distance_m"]), sigma, length(lo), length(hi), r.get("quality", ""), "; ".join(r.get("reasons", [])),
                 r["method"], r["fit"], length(r["basic_distance_m"]),
                 *(f"{v:.1f}" for v in (*r["p1"], *r["p2"])), *(length(v) for v in (*r["p1_m"], *r["p2_m"])),
                 r["n_samples"], r["n_valid"], r["n_support"], int(r["gap_detected"]), "; ".join(r["warnings"]),
                 f"{base_url}api/measurements/{r['id']}/color.png"]
            )  # fmt: skip
        return buf.getvalue()

