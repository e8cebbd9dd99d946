"""The history's size cap: which saved frames to delete so that the frame files fit a number of bytes.

The oldest frames go first, except those a pinned measurement uses and the newest frame; their
rows stay with ``file = ''``, so their measurements keep their numbers without a frame to reopen.
"""

from __future__ import annotations

import sqlite3


def drop_over_cap(db: sqlite3.Connection, max_bytes: int) -> list[str]:
    """Mark the frames to delete in ``db`` (the caller holds the write lock and deletes the files after)
    until the frame files total at most ``max_bytes``; the file names to delete."""
    total = db.execute("SELECT COALESCE(SUM(bytes), 0) FROM frames WHERE file != ''").fetchone()[0]
    if total <= max_bytes:
        return []
    rows = db.execute(
        "SELECT uid, file, bytes FROM frames WHERE file != '' AND uid NOT IN "
        "(SELECT frame_uid FROM measurements WHERE pinned=1) ORDER BY created, rowid"
    ).fetchall()[:-1]
    victims = []
    for r in rows:
        if total <= max_bytes:
            break
        victims.append(r)
        total -= r["bytes"]
    db.executemany("UPDATE frames SET file='' WHERE uid=?", [(r["uid"],) for r in victims])
    return [r["file"] for r in victims]
