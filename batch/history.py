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

from batch.tasks import KINDS, LEAST_CLICKS, OPTION_FIELDS, SEGMENT, Task, TaskError, parse_clicks

HISTORY_KIND = "history"


class HistoryError(TaskError):
    """The history database or one of its saved frames cannot be read; names the file."""


def history_tasks(db: Path) -> list[Task]:
    """One task per stored measurement of every kind, oldest first: a segment's two clicks, a shape's
    clicks (and a height's base clicks) as the service stored them, with its stored options. The
    database is read here, once: a task's frame is the absolute path of its saved frame file
    (workers only read that file, never the database, which SQLite cannot share over a network
    filesystem), or ``missing:UID`` / ``dropped:UID`` for a frame that was never saved or was
    deleted by the service's size cap. A row whose kind or clicks cannot be read is that task's
    error row (``error_field`` "kind" or "points")."""
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
        source = f"{HISTORY_KIND}:{db}"
        if r["kind"] == SEGMENT:
            tasks.append(Task(i, source, frame, (r["p1_x"], r["p1_y"]), (r["p2_x"], r["p2_y"]), options, extra))
        else:
            tasks.append(_shape_task(i, source, frame, r["kind"], r["extra"], options, extra))
    return tasks


def _shape_task(i: int, source: str, frame: str, kind: str, stored: str, options: dict, extra: dict) -> Task:
    """The task of a stored shape: its kind and the clicks its row's ``extra`` keeps (an error task
    naming ``kind`` or ``points`` when they cannot be read)."""
    none = (None, None)
    if kind not in KINDS:
        return Task(i, source, frame, none, none, options, extra, f"kind {kind!r} is not a kind this version measures", "kind", None)
    try:
        shape = json.loads(stored or "{}").get("shape") or {}
        least = LEAST_CLICKS[kind]
        points = parse_clicks("points", shape.get("points"), least, least if least == 1 else None, f"a {kind}")
        on = parse_clicks("on", shape["on"], 1, what="a height's base") if kind == "height" and shape.get("on") else None
    except (TaskError, ValueError, AttributeError) as exc:
        return Task(i, source, frame, none, none, options, extra, f"the stored clicks of this {kind} cannot be read ({exc})", "points", kind)
    return Task(i, source, frame, none, none, options, extra, kind=kind, points=points, on=on)


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
