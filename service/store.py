"""Measurement history in SQLite (WAL), with each measured frame saved alongside as ``.npz``.

The database holds every :class:`measure.Measurement` field, the frame id and clicked points,
the options and a small thumbnail. The frame itself (image, disparity, confidence, camera,
baseline) goes to ``<db stem>-frames/<uid>.npz`` once, however many measurements use it, so
history survives a restart and a measurement can be re-opened on exactly its frame. Frames are
written by a background thread (bounded queue) so a measurement answers without waiting for the
disk; ``close()`` drains the queue, so a clean shutdown loses nothing.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import queue
import sqlite3
import threading
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, PinholeCamera

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
    # JSON: result fields without a column (quality, reasons, interval_m, ...), frame_index, name, note
    ("measurements", "extra", "TEXT NOT NULL DEFAULT '{}'"),
)

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


_FIXED_RESULT_KEYS = frozenset(
    ("distance_m", "method", "fit", "p1_m", "p2_m", "basic_distance_m", "uncertainty_m", "n_samples", "n_valid",
     "n_support", "samples_px", "support", "gap_detected", "warnings", "elapsed_ms")
)  # fmt: skip


class StoreError(RuntimeError):
    """The history database or a saved frame cannot be read or written; names the file."""


def _json_meta(meta: Any) -> dict[str, Any]:
    """The JSON-serialisable scalar part of a frame's meta (e.g. not the simulator's Truth object)."""
    out: dict[str, Any] = {}
    for k, v in dict(meta or {}).items():
        if isinstance(v, (str, int, float, bool)) or v is None:
            out[str(k)] = v
    return out


def save_frame(frame: Frame, path: Path) -> None:
    """Write a frame to ``path`` (.npz) atomically: a crash leaves either the old file or the new one."""
    cam = frame.camera
    arrays: dict[str, Any] = {
        "image": frame.image,
        "disparity": frame.disparity,
        "camera": np.array([cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height], dtype=np.float64),
        "numbers": np.array([frame.baseline_m, frame.doffs, frame.timestamp], dtype=np.float64),
        "meta": np.array(json.dumps(_json_meta(frame.meta))),
    }
    if frame.confidence is not None:
        arrays["confidence"] = frame.confidence
    tmp = path.with_suffix(".tmp.npz")
    with open(tmp, "wb") as fh:
        # np.savez_compressed's zlib level 6 costs ~4x level 1 for a few % of size; frames are noisy anyway.
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
            for name, value in arrays.items():
                with zf.open(name + ".npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def load_frame(path: Path) -> Frame:
    """Read a frame written by :func:`save_frame`."""
    try:
        with np.load(path, allow_pickle=False) as z:
            fx, fy, cx, cy, w, h = z["camera"].tolist()
            baseline, doffs, ts = z["numbers"].tolist()
            return Frame(
                image=z["image"],
                disparity=z["disparity"],
                camera=PinholeCamera(fx=fx, fy=fy, cx=cx, cy=cy, width=int(w), height=int(h)),
                baseline_m=baseline,
                doffs=doffs,
                confidence=z["confidence"] if "confidence" in z.files else None,
                timestamp=ts,
                meta=json.loads(str(z["meta"])),
            )
    except (OSError, KeyError, ValueError) as exc:
        raise StoreError(f"cannot read saved frame {path}: {exc}; the history entry needs this file") from exc


def _num(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


class Store:
    """Thread-safe measurement history; ``Store(path)`` creates the database and frames folder."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.frames_dir = self.path.with_name(self.path.stem + "-frames")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.frames_dir.mkdir(exist_ok=True)
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
            for table, column, decl in _MIGRATIONS:
                if column not in {r[1] for r in self._db.execute(f"PRAGMA table_info({table})")}:
                    self._db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"cannot open the history database {self.path}: {exc}; pass --db with a writable path") from exc
        self._db.row_factory = sqlite3.Row
        self._lock = threading.Lock()
        self._pending: dict[str, Frame] = {}
        self._queue: queue.Queue[str | None] = queue.Queue(maxsize=16)  # backpressure: bounded memory
        self._writer = threading.Thread(target=self._write_frames, name="depthruler-store", daemon=True)
        self._writer.start()
        self.write_errors: list[str] = []

    def close(self) -> None:
        """Write the frames still queued, then close the database."""
        self._queue.put(None)
        self._writer.join()
        with self._lock:
            self._db.close()

    def flush(self) -> None:
        """Block until every queued frame is on disk."""
        self._queue.join()

    def ensure_frame(self, uid: str, frame: Frame) -> None:
        """Queue ``frame`` for saving under ``uid`` unless it is saved or queued already."""
        with self._lock:
            if uid in self._pending or self._db.execute("SELECT 1 FROM frames WHERE uid=?", (uid,)).fetchone():
                return
            self._pending[uid] = frame
        self._queue.put(uid)

    def _write_frames(self) -> None:
        while (uid := self._queue.get()) is not None:
            try:
                self._write_frame(uid)
            except Exception as exc:  # noqa: BLE001 — a full disk must not kill the writer; report it
                self.write_errors.append(f"saving frame {uid} failed: {exc}")
            finally:
                with self._lock:
                    self._pending.pop(uid, None)
                self._queue.task_done()
        self._queue.task_done()

    def _write_frame(self, uid: str) -> None:
        with self._lock:
            frame = self._pending.get(uid)
        if frame is None:
            return
        name = f"{uid}.npz"
        save_frame(frame, self.frames_dir / name)
        h, w = frame.disparity.shape
        with self._lock:
            if not self._db.execute("SELECT 1 FROM measurements WHERE frame_uid=? LIMIT 1", (uid,)).fetchone():
                orphan = True  # its measurements were deleted while it was queued
            else:
                orphan = False
                self._db.execute(
                    "INSERT OR IGNORE INTO frames(uid, file, width, height, timestamp, source, created) VALUES (?,?,?,?,?,?,?)",
                    (uid, name, w, h, float(frame.timestamp), str(frame.meta.get("source", "")), time.time()),
                )
        if orphan:
            (self.frames_dir / name).unlink(missing_ok=True)

    def frame(self, uid: str) -> Frame:
        with self._lock:
            pending = self._pending.get(uid)
            row = self._db.execute("SELECT file FROM frames WHERE uid=?", (uid,)).fetchone()
        if pending is not None:
            return pending
        if row is None:
            raise StoreError(f"the frame {uid} of this measurement was not saved in {self.frames_dir} (lost in a crash?)")
        return load_frame(self.frames_dir / row["file"])

    def add(
        self,
        *,
        frame_id: int,
        frame_uid: str,
        source: str,
        p1: tuple[float, float],
        p2: tuple[float, float],
        options: dict[str, Any],
        result: dict[str, Any],
        thumb: bytes | None,
        context: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """Insert one measurement (``result`` is ``Measurement.to_dict()``) and return its stored record.
        Result fields without a column of their own (e.g. ``quality``, ``reasons``, ``interval_m``) and
        ``context`` (e.g. ``frame_index`` of a replay) are kept in the ``extra`` JSON column."""
        extra = {k: v for k, v in result.items() if k not in _FIXED_RESULT_KEYS} | (context or {})
        created = time.time()
        values = (
            created, frame_id, frame_uid, source, float(p1[0]), float(p1[1]), float(p2[0]), float(p2[1]),
            json.dumps(options), result["distance_m"], result["method"], result["fit"], json.dumps(result["p1_m"]),
            json.dumps(result["p2_m"]), result["basic_distance_m"], result["uncertainty_m"], result["n_samples"],
            result["n_valid"], result["n_support"], json.dumps(result["samples_px"]), json.dumps(result["support"]),
            int(result["gap_detected"]), json.dumps(result["warnings"]), result["elapsed_ms"], thumb, json.dumps(extra),
        )  # fmt: skip
        with self._lock:
            cur = self._db.execute(
                "INSERT INTO measurements(created, frame_id, frame_uid, source, p1_x, p1_y, p2_x, p2_y, options, "
                "distance_m, method, fit, p1_m, p2_m, basic_distance_m, uncertainty_m, n_samples, n_valid, "
                "n_support, samples_px, support, gap_detected, warnings, elapsed_ms, thumb, extra) "
                "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                values,
            )
            mid = cur.lastrowid
        record = self.get(mid)
        assert record is not None
        return record

    @staticmethod
    def _record(row: sqlite3.Row) -> dict[str, Any]:
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
            "samples_px": json.loads(row["samples_px"]),
            "support": json.loads(row["support"]),
            "gap_detected": bool(row["gap_detected"]),
            "warnings": json.loads(row["warnings"]),
            "elapsed_ms": row["elapsed_ms"],
        }

    def get(self, mid: int) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM measurements WHERE id=?", (mid,)).fetchone()
        return self._record(row) if row else None

    def list(self, limit: int = 1000) -> list[dict[str, Any]]:
        """Newest first."""
        with self._lock:
            rows = self._db.execute("SELECT * FROM measurements ORDER BY id DESC LIMIT ?", (limit,)).fetchall()
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
        return self.get(mid)

    def thumb(self, mid: int) -> bytes | None:
        with self._lock:
            row = self._db.execute("SELECT thumb FROM measurements WHERE id=?", (mid,)).fetchone()
        return bytes(row["thumb"]) if row and row["thumb"] is not None else None

    def delete(self, mid: int) -> bool:
        """Delete a measurement; its saved frame goes too once no measurement refers to it."""
        with self._lock:
            row = self._db.execute("SELECT frame_uid FROM measurements WHERE id=?", (mid,)).fetchone()
            if row is None:
                return False
            uid = row["frame_uid"]
            self._db.execute("DELETE FROM measurements WHERE id=?", (mid,))
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
