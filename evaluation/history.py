"""The service's measurement history, read-only, for `depthruler batch --from-history DB`.

`evaluation` does not import `service`, so this reads the history database itself. What it relies
on (the service's `service/store.py` writes it) and nothing more:

- SQLite table ``measurements`` with the columns ``id``, ``frame_uid``, ``source``, ``p1_x``,
  ``p1_y``, ``p2_x``, ``p2_y`` and ``options`` (a JSON object of MeasureOptions fields), plus the
  stored result (``distance_m``, ``uncertainty_m``, ... as the service wrote them);
- table ``frames`` with ``uid`` and ``file``: the saved frame, relative to the folder
  ``<DB stem>-frames/`` beside the database;
- a saved frame file, recognised by its name: ``.npz`` (arrays ``image``, ``disparity``, optional
  ``confidence``, ``camera`` = [fx, fy, cx, cy, width, height], ``numbers`` = [baseline_m, doffs,
  timestamp], ``meta`` = a JSON string). Another format (the service may move to PNG/JPEG files)
  needs a loader in :data:`FRAME_LOADERS`; until then its rows come out as error rows naming the
  file, and nothing is written to the database or its frames.

The database is opened with SQLite's ``mode=ro``, so a running service keeps writing while a batch
reads (WAL); a batch never changes the history.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, PinholeCamera

from .tasks import OPTION_FIELDS, Task, TaskError

HISTORY_KIND = "history"


class HistoryError(TaskError):
    """The history database or one of its saved frames cannot be read; names the file."""


def frames_dir(db: Path) -> Path:
    return db.with_name(db.stem + "-frames")


def connect(db: Path) -> sqlite3.Connection:
    """A read-only connection to the history database."""
    if not db.is_file():
        raise HistoryError(f"{db} does not exist; give the history database the service writes (`depthruler serve --db`)")
    try:
        con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True, check_same_thread=False)
        con.row_factory = sqlite3.Row
        con.execute("SELECT id, frame_uid, source, p1_x, p1_y, p2_x, p2_y, options FROM measurements LIMIT 1").fetchall()
    except sqlite3.Error as exc:
        raise HistoryError(f"{db} is not a depthruler history database ({exc})") from exc
    return con


def history_tasks(db: Path) -> list[Task]:
    """One task per stored measurement, oldest first; the frame is the saved frame's uid."""
    db = db.resolve()
    con = connect(db)
    try:
        rows = con.execute("SELECT id, frame_uid, source, p1_x, p1_y, p2_x, p2_y, options FROM measurements ORDER BY id").fetchall()
    finally:
        con.close()
    tasks = []
    for i, r in enumerate(rows):
        try:
            stored = json.loads(r["options"])
        except json.JSONDecodeError as exc:
            raise HistoryError(f"{db}: measurement {r['id']} has unreadable options ({exc})") from exc
        options = {k: v for k, v in stored.items() if k in OPTION_FIELDS}
        extra = {"history_id": int(r["id"]), "history_source": r["source"], "frame_uid": r["frame_uid"]}
        tasks.append(Task(i, f"{HISTORY_KIND}:{db}", r["frame_uid"], (r["p1_x"], r["p1_y"]), (r["p2_x"], r["p2_y"]), options, extra))
    return tasks


def stored_results(db: Path) -> dict[int, dict[str, Any]]:
    """history id -> the measurement as stored (the columns of ``measurements``, JSON decoded)."""
    con = connect(db)
    try:
        rows = con.execute("SELECT * FROM measurements ORDER BY id").fetchall()
    finally:
        con.close()
    out = {}
    for r in rows:
        rec = {k: r[k] for k in r.keys() if k != "thumb"}
        for k, v in rec.items():
            if isinstance(v, str) and v[:1] in "[{":
                try:
                    rec[k] = json.loads(v)
                except json.JSONDecodeError:
                    pass
        out[int(r["id"])] = rec
    return out


def _load_npz(path: Path) -> Frame:
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


# saved-frame file suffix -> loader
FRAME_LOADERS: dict[str, Callable[[Path], Frame]] = {".npz": _load_npz}


class HistoryFrames:
    """Saved frames of a history database by uid (a batch worker opens one per database)."""

    def __init__(self, db: Path) -> None:
        self.db = Path(db)
        self._con = connect(self.db)

    def frame(self, uid: int | str) -> Frame:
        row = self._con.execute("SELECT file FROM frames WHERE uid=?", (str(uid),)).fetchone()
        if row is None:
            raise HistoryError(f"the frame {uid} is not saved in {self.db} (it was lost in a crash or is still being written)")
        path = frames_dir(self.db) / row["file"]
        loader = FRAME_LOADERS.get(path.suffix.lower())
        if loader is None:
            raise HistoryError(f"{path}: saved frames of type {path.suffix!r} are not readable by this version (it reads {', '.join(FRAME_LOADERS)})")
        try:
            return loader(path)
        except (OSError, KeyError, ValueError) as exc:
            raise HistoryError(f"cannot read the saved frame {path}: {exc}") from exc

    def close(self) -> None:
        self._con.close()
