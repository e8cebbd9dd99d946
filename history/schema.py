"""The history database's schema, written once: its tables, columns, migrations and connections.

Two tables: ``frames`` (one row per saved frame file, ``file`` relative to :func:`frames_dir`;
``file = ''`` once the size cap deleted the file) and ``measurements`` (one row per measurement:
clicked points in px, options as JSON, the result's fields in metres, and ``extra``, a JSON object
of the result's newer fields, the name, the note and the request's context). ``kind`` says what a
row measured: "segment" (two clicks; every row of a database from before shapes), or a shape kind
("box", "height", "path", "area") whose clicks and result live in ``extra`` (:mod:`history.shape_records`).

The service writes through :func:`open_writer` (WAL, synchronous=FULL, checkpoints left to the
store's own thread); its threads read through :func:`open_reader`; anyone else (the batch) reads
through :func:`open_read_only`, which also checks that the file is a history database.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from history.errors import HistoryUnreadable

FRAMES_COLUMNS = (
    ("uid", "TEXT PRIMARY KEY"),
    ("file", "TEXT NOT NULL"),
    ("width", "INTEGER NOT NULL"),
    ("height", "INTEGER NOT NULL"),
    ("timestamp", "REAL NOT NULL"),
    ("source", "TEXT NOT NULL"),
    ("created", "REAL NOT NULL"),
)
MEASUREMENTS_COLUMNS = (
    ("id", "INTEGER PRIMARY KEY AUTOINCREMENT"),
    ("created", "REAL NOT NULL"),
    ("frame_id", "INTEGER NOT NULL"),
    ("frame_uid", "TEXT NOT NULL REFERENCES frames(uid)"),
    ("source", "TEXT NOT NULL"),
    ("p1_x", "REAL NOT NULL"), ("p1_y", "REAL NOT NULL"), ("p2_x", "REAL NOT NULL"), ("p2_y", "REAL NOT NULL"),
    ("options", "TEXT NOT NULL"),
    ("distance_m", "REAL"),
    ("method", "TEXT NOT NULL"),
    ("fit", "TEXT NOT NULL"),
    ("p1_m", "TEXT NOT NULL"),
    ("p2_m", "TEXT NOT NULL"),
    ("basic_distance_m", "REAL"),
    ("uncertainty_m", "REAL"),
    ("n_samples", "INTEGER NOT NULL"),
    ("n_valid", "INTEGER NOT NULL"),
    ("n_support", "INTEGER NOT NULL"),
    ("samples_px", "TEXT NOT NULL"),
    ("support", "TEXT NOT NULL"),
    ("gap_detected", "INTEGER NOT NULL"),
    ("warnings", "TEXT NOT NULL"),
    ("elapsed_ms", "REAL NOT NULL"),
    ("thumb", "BLOB"),
)  # fmt: skip
MIGRATIONS = (  # columns added since the first schema: (table, column, declaration)
    ("frames", "bytes", "INTEGER NOT NULL DEFAULT 0"),
    ("measurements", "pinned", "INTEGER NOT NULL DEFAULT 0"),
    ("measurements", "extra", "TEXT NOT NULL DEFAULT '{}'"),
    ("measurements", "kind", "TEXT NOT NULL DEFAULT 'segment'"),  # rows from before shapes were all segments
)
SEGMENT = "segment"
FRAME_INSERT = ("uid", "file", "width", "height", "timestamp", "source", "created", "bytes")
MEASUREMENT_INSERT = tuple(name for name, _ in MEASUREMENTS_COLUMNS if name != "id") + ("extra", "kind")
SLIM_COLUMNS = tuple(
    name for name, _ in MEASUREMENTS_COLUMNS if name not in ("samples_px", "support", "thumb")
) + ("pinned", "extra", "kind")  # every column but the per-sample arrays and the thumbnail
# What a reader outside the service relies on (checked by open_read_only).
READ_COLUMNS = {
    "measurements": ("id", "frame_uid", "source", "p1_x", "p1_y", "p2_x", "p2_y", "options"),
    "frames": ("uid", "file"),
}


def frames_dir(db: str | Path) -> Path:
    """The folder of the saved frames of history database ``db``: ``<db stem>-frames`` beside it."""
    db = Path(db)
    return db.with_name(db.stem + "-frames")


def _ddl() -> str:
    tables = (("frames", FRAMES_COLUMNS), ("measurements", MEASUREMENTS_COLUMNS))
    return "\n".join(
        f"CREATE TABLE IF NOT EXISTS {name} ({', '.join(f'{c} {decl}' for c, decl in columns)});" for name, columns in tables
    )


def insert_sql(table: str, columns: tuple[str, ...], verb: str = "INSERT") -> str:
    """``INSERT INTO table(columns) VALUES (?, ...)``, with ``verb`` e.g. ``INSERT OR IGNORE``."""
    return f"{verb} INTO {table}({', '.join(columns)}) VALUES ({','.join('?' * len(columns))})"


def open_writer(path: Path) -> sqlite3.Connection:
    """The one writing connection: creates or migrates the schema; WAL with synchronous=FULL (a
    committed row survives power loss), automatic checkpoints off (the store runs them on a thread).
    Raises sqlite3.Error or OSError."""
    db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
    try:
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=FULL")
        db.execute("PRAGMA wal_autocheckpoint=0")
        db.executescript(_ddl())
        for table, column, decl in MIGRATIONS:
            if column not in {r[1] for r in db.execute(f"PRAGMA table_info({table})")}:
                db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
    except BaseException:
        db.close()
        raise
    db.row_factory = sqlite3.Row
    return db


def open_reader(path: Path) -> sqlite3.Connection:
    """A query-only connection of the writing process (one per thread: WAL reads never wait for a commit)."""
    conn = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
    conn.row_factory = sqlite3.Row
    conn.execute("PRAGMA query_only=1")
    return conn


def open_read_only(db: Path) -> sqlite3.Connection:
    """A read-only connection (SQLite ``mode=ro``) to history database ``db`` for a process that does
    not own it (a running service may keep writing). Raises :class:`HistoryUnreadable` when ``db`` is
    missing or lacks a table or column of :data:`READ_COLUMNS`."""
    if not db.is_file():
        raise HistoryUnreadable(f"{db} does not exist; give the history database the service writes (`depthruler serve --db`)")
    try:
        con = sqlite3.connect(f"{db.resolve().as_uri()}?mode=ro", uri=True, check_same_thread=False)
    except sqlite3.Error as exc:
        raise HistoryUnreadable(f"{db} cannot be opened read-only ({exc})") from exc
    con.row_factory = sqlite3.Row
    try:
        for table, columns in READ_COLUMNS.items():
            con.execute(f"SELECT {', '.join(columns)} FROM {table} LIMIT 1").fetchall()
    except sqlite3.Error as exc:
        con.close()
        raise HistoryUnreadable(f"{db} is not a depthruler history database ({exc})") from exc
    return con


def measurement_inputs(con: sqlite3.Connection) -> list[sqlite3.Row]:
    """What re-measuring every stored measurement needs, oldest first: ``id``, ``kind`` ("segment" or
    a shape kind), ``frame_uid``, ``source``, ``p1_x`` .. ``p2_y`` (px), ``options`` (JSON), ``extra``
    (JSON; a shape's clicks are its ``shape``, :mod:`history.shape_records`) and its frame's ``file``
    (None: no frame row; '': deleted by the size cap). A database the service has not migrated yet
    (no ``kind`` or ``extra`` column) holds segments only."""
    have = {r[1] for r in con.execute("PRAGMA table_info(measurements)")}
    kind = "m.kind" if "kind" in have else f"'{SEGMENT}'"
    extra = "m.extra" if "extra" in have else "'{}'"
    return con.execute(
        f"SELECT m.id, {kind} AS kind, m.frame_uid, m.source, m.p1_x, m.p1_y, m.p2_x, m.p2_y, m.options, {extra} AS extra, f.file "
        "FROM measurements m LEFT JOIN frames f ON f.uid = m.frame_uid ORDER BY m.id"
    ).fetchall()
