"""WAL checkpoints of the history database on a thread of their own, beside the commits.

A checkpoint copies the WAL's committed pages into the database file. It runs when the store has
been quiet for :data:`QUIET_S` or :data:`ROWS` rows wait, PASSIVE (it never waits for a writer or
a reader); past :data:`WAL_RESTART_PAGES` it finishes under the store's write lock so the WAL can
start over. The rows are durable already (the WAL is fsynced at each commit); the reasons and
their measurement are in docs/decisions/history-checkpoints.md.
"""

from __future__ import annotations

import sqlite3
import threading
import time
from pathlib import Path

QUIET_S = 1.0
ROWS = 100
WAL_RESTART_PAGES = 1000


class Checkpointer:
    """Runs checkpoints of database ``path`` until :meth:`close`; ``write_lock`` is the store's."""

    def __init__(self, path: Path, write_lock: threading.Lock) -> None:
        self.path = path
        self._write_lock = write_lock
        self._lock = threading.Lock()
        self._uncopied = 0  # rows committed since the last checkpoint
        self._last_commit = time.monotonic()
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._run, name="depthruler-checkpoint", daemon=True)
        self._thread.start()

    def committed(self, rows: int) -> None:
        """``rows`` rows were committed just now."""
        with self._lock:
            self._uncopied += rows
            self._last_commit = time.monotonic()

    def close(self) -> None:
        self._closing.set()
        self._thread.join()

    def _due(self) -> bool:
        with self._lock:
            due = self._uncopied >= ROWS or (self._uncopied > 0 and time.monotonic() - self._last_commit >= QUIET_S)
            if due:
                self._uncopied = 0  # rows committed from now on count toward the next pass
            return due

    def _run(self) -> None:
        try:
            conn = sqlite3.connect(self.path, isolation_level=None)
        except sqlite3.Error:
            return  # out of file descriptors at start: SQLite's own checkpoint at close still runs
        try:
            conn.execute("PRAGMA synchronous=FULL")
            while not self._closing.wait(min(0.25, QUIET_S)):
                if not self._due():
                    continue
                try:
                    _, wal_pages, copied = conn.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
                    if wal_pages > WAL_RESTART_PAGES and copied < wal_pages:
                        # Commits kept coming during the pass, so the WAL never starts over and grows:
                        # copy the few pages left while no commit runs.
                        with self._write_lock:
                            conn.execute("PRAGMA wal_checkpoint(PASSIVE)")
                except sqlite3.Error:
                    self.committed(1)  # a full disk or a busy database: try again later
        finally:
            conn.close()
