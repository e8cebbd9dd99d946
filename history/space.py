"""Room on the history's disk: whether the next frame fits, and a reserve so that edits commit on a full disk.

- :func:`is_full`: an OSError or sqlite3.Error that means the disk (or the quota) is full.
- :class:`Space` follows what the next frame needs (the largest of the last
  :data:`RECENT_FRAMES` saved frames, bytes) and compares it, plus :data:`COMMIT_HEADROOM`
  for the row's commit, with the free bytes of the folder's file system (``statvfs``, cheap: at
  every health request). After a failed write it stays short until a probe of that size writes.
- The reserve is a file of :data:`RESERVE_BYTES` in the frames folder. A delete, pin or edit
  that SQLite refuses for want of space releases it and commits in the room it leaves (deleting
  is how a person frees space); it is laid again once there is room.
"""

from __future__ import annotations

import errno
import os
import sqlite3
import threading
import time
from collections import deque
from pathlib import Path

from history import frame_file
from history.frame_file import TMP_SUFFIX

RESERVE_BYTES = 1 << 20
COMMIT_HEADROOM = 256 << 10  # a row's pages in the WAL, and its index (see docs/decisions/full-disk.md)
RECENT_FRAMES = 16
PROBE_INTERVAL_S = 0.5
RESERVE_NAME = ".reserve"
_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


def is_full(exc: BaseException) -> bool:
    """Whether ``exc`` says the disk or the quota is full (ENOSPC, EDQUOT, SQLITE_FULL)."""
    if isinstance(exc, OSError):
        return exc.errno in _FULL_ERRNOS
    return isinstance(exc, sqlite3.Error) and (
        getattr(exc, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL or "full" in str(exc).lower()
    )


def free_bytes(folder: Path) -> int:
    """Bytes an unprivileged writer may still use on the file system of ``folder``."""
    st = os.statvfs(folder)
    return st.f_bavail * st.f_frsize


class Space:
    """Room for the next frame in ``folder`` (thread-safe); see the module docstring."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.reserve = folder / RESERVE_NAME
        self._lock = threading.Lock()
        self._recent: deque[int] = deque(maxlen=RECENT_FRAMES)
        self._failed = ""  # why the last write failed, until a write or a probe succeeds
        self._next_probe = 0.0

    @property
    def need(self) -> int | None:
        """Bytes the next frame needs (None before any frame of this history was saved)."""
        with self._lock:
            return max(self._recent) if self._recent else None

    def seed(self, sizes: list[int]) -> None:
        """The sizes (bytes) of the frames saved so far, oldest first (from the database, at start)."""
        with self._lock:
            self._recent.extend(b for b in sizes[-RECENT_FRAMES:] if b > 0)

    def free(self) -> int | None:
        """Free bytes now (None when the file system cannot say)."""
        try:
            return free_bytes(self.folder)
        except OSError:
            return None

    def saved(self, nbytes: int) -> None:
        """A frame of ``nbytes`` was written: it is what the next ones will need, and space is there."""
        with self._lock:
            if nbytes > 0:
                self._recent.append(nbytes)
            self._failed = ""

    def expect(self, nbytes: int) -> None:
        """The next frame will take about ``nbytes`` (its encoded size), when no frame was saved yet."""
        with self._lock:
            if not self._recent and nbytes > 0:
                self._recent.append(nbytes)

    def wrote(self) -> None:
        """A write (a commit) went through: the disk is not full."""
        with self._lock:
            self._failed = ""

    @property
    def failed_reason(self) -> str:
        """Why the last write failed ("" once a write or probe went through)."""
        with self._lock:
            return self._failed

    def failed(self, reason: str) -> None:
        with self._lock:
            self._failed = reason
            self._next_probe = 0.0

    def shortage(self) -> str:
        """Why the next frame would not be stored ("" when it would fit): the free bytes against what it
        and its commit need, plus the reserve's room while the reserve is missing; or the last failed
        write, until a probe write of that size succeeds."""
        frame_need = (self.need or 0) + COMMIT_HEADROOM
        self.lay_reserve()
        free = self.free()
        if free is None:
            return f"cannot read the free space of {self.folder}"
        kept = 0 if self.reserve.exists() else RESERVE_BYTES
        if free < frame_need + kept:
            also = f" and {kept / 1e6:.2f} MB kept for deleting and editing" if kept else ""
            return (
                f"the disk holding {self.folder} has {free / 1e6:.2f} MB free, the next frame needs {frame_need / 1e6:.2f} MB"
                f"{also}; free space there (delete measurements or files) or lower --history-max-gb"
            )
        with self._lock:
            failed, probe_due = self._failed, time.monotonic() >= self._next_probe
            if failed and probe_due:
                self._next_probe = time.monotonic() + PROBE_INTERVAL_S
        if failed and probe_due and self._probe(frame_need):
            with self._lock:
                self._failed = failed = ""
        return failed

    def _probe(self, nbytes: int) -> bool:
        probe = self.folder / f".probe{TMP_SUFFIX}"
        try:
            frame_file.write_durably(probe, b"\0" * nbytes)  # as a frame is written
            return True
        except OSError:
            return False
        finally:
            probe.unlink(missing_ok=True)

    def lay_reserve(self) -> None:
        """Create the reserve file when it is missing and the disk has room for it beside the next
        frame; a failure leaves it missing (tried again later)."""
        if self.reserve.exists():
            return
        free = self.free()
        if free is None or free < (self.need or 0) + COMMIT_HEADROOM + RESERVE_BYTES:
            return
        try:
            fd = os.open(self.reserve, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except OSError:
            return
        try:
            os.posix_fallocate(fd, 0, RESERVE_BYTES)
            os.fsync(fd)
        except OSError:
            os.close(fd)
            self.reserve.unlink(missing_ok=True)
            return
        os.close(fd)

    def release_reserve(self) -> bool:
        """Delete the reserve file to make room; whether there was one."""
        try:
            self.reserve.unlink()
            return True
        except FileNotFoundError:
            return False
