"""The service's measurement history, read-only, as batch tasks: `depthruler batch --from-history DB`.

The history package owns the database and its frame files: :func:`history.schema.open_read_only`
opens the database (SQLite ``mode=ro``: a running service may keep writing) and checks it is one,
:func:`history.schema.measurement_inputs` reads what re-measuring needs, and
:func:`history.frame_file.load_frame_file` reads a saved frame. The database is read once, by
the caller; workers read only the frame files. A batch never changes the history.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

from history import schema
from history.errors import HistoryUnreadable
from history.frame_file import SUFFIX, load_frame_file
from measure import Frame

from batch.tasks import OPTION_FIELDS, Task, TaskError

HISTORY_KIND = "history"


class HistoryError(TaskError):
    """The history database or one of its saved frames cannot be read; names the file."""


def history_tasks(db: Path) -> list[Task]:
    """One task per stored measurement, oldest first. The database is read here, once: a task's
    frame is the absolute path of its saved frame file (workers only read that file, never the
    database, which SQLite cannot share over a network filesystem), or ``missing:UID`` /
    ``dropped:UID`` for a frame that was never saved or was deleted by the service's size cap."""
    db = db.resolve()
    try:
        con = schema.open_read_only(db)
    except HistoryUnreadable as exc:
        raise HistoryError(str(exc)) from None
    try:
        rows = schema.measurement_inputs(con)
    finally:
        con.close()
    folder = schema.frames_dir(db)
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
