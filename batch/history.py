"""The service's measurement history, read-only, for `depthruler batch --from-history DB`.

`evaluation` does not import `service`, so this reads the history database itself. What it relies
on (the service's `history/store.py` writes it) and nothing more:

- SQLite table ``measurements`` with the columns ``id``, ``frame_uid``, ``source``, ``p1_x``,
  ``p1_y``, ``p2_x``, ``p2_y`` and ``options`` (a JSON object of MeasureOptions fields), plus the
  stored result (``distance_m``, ``uncertainty_m``, ... as the service wrote them);
- table ``frames`` with ``uid`` and ``file``: the saved frame, relative to the folder
  ``<DB stem>-frames/`` beside the database;
- a saved frame file, ``.frame`` or the ``.npz`` of earlier versions, read by
  :func:`history.frame_file.load_frame_file` (the module the service writes them with). A frame
  whose ``file`` is empty was deleted by the service's size cap; its measurements come out as
  error rows.

The database is read once, by the caller, with SQLite's ``mode=ro`` (a running service keeps
writing meanwhile); workers read only the frame files. A batch never changes the history.
"""

from __future__ import annotations

import json
import sqlite3
import zipfile
from pathlib import Path

from history.frame_file import SUFFIX, load_frame_file
from measure import Frame

from batch.tasks import OPTION_FIELDS, Task, TaskError

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
    """One task per stored measurement, oldest first. The database is read here, once: a task's
    frame is the absolute path of its saved frame file (workers only read that file, never the
    database, which SQLite cannot share over a network filesystem), or ``missing:UID`` /
    ``dropped:UID`` for a frame that was never saved or was deleted by the service's size cap."""
    db = db.resolve()
    con = connect(db)
    try:
        rows = con.execute(
            "SELECT m.id, m.frame_uid, m.source, m.p1_x, m.p1_y, m.p2_x, m.p2_y, m.options, f.file "
            "FROM measurements m LEFT JOIN frames f ON f.uid = m.frame_uid ORDER BY m.id"
        ).fetchall()
    finally:
        con.close()
    folder = frames_dir(db)
    tasks = []
    for i, r in enumerate(rows):
        try:
            stored = json.loads(r["options"])
        except json.JSONDecodeError as exc:
            raise HistoryError(f"{db}: measurement {r['id']} has unreadable options ({exc})") from exc
        options = {k: v for k, v in stored.items() if k in OPTION_FIELDS}
        uid = r["frame_uid"]
        frame = str(folder / r["file"]) if r["file"] else f"{'missing' if r['file'] is None else 'dropped'}:{uid}"
        extra = {"history_id": int(r["id"]), "history_source": r["source"], "frame_uid": uid}
        tasks.append(Task(i, f"{HISTORY_KIND}:{db}", frame, (r["p1_x"], r["p1_y"]), (r["p2_x"], r["p2_y"]), options, extra))
    return tasks


class HistoryFrames:
    """Saved frames of a history database, by the keys :func:`history_tasks` gives (file paths)."""

    def __init__(self, db: Path) -> None:
        self.db = Path(db)

    def frame(self, key: int | str) -> Frame:
        key = str(key)
        if key.startswith("missing:"):
            raise HistoryError(f"the frame {key[8:]} is not saved in {self.db} (it was lost in a crash or was still being written)")
        if key.startswith("dropped:"):
            raise HistoryError(f"the frame {key[8:]} was deleted from {self.db}'s history to keep it under its size cap; only its numbers are kept")
        path = Path(key)
        if path.suffix.lower() not in (".npz", SUFFIX):
            raise HistoryError(f"{path}: saved frames of type {path.suffix!r} are not readable by this version (it reads .npz, {SUFFIX})")
        try:
            return load_frame_file(path)
        except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile) as exc:
            raise HistoryError(f"cannot read the saved frame {path}: {exc}") from exc

    def close(self) -> None:
        pass
