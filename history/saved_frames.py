"""The saved frame files of a history (``<uid>.frame`` in :func:`history.schema.frames_dir`), and
their presaving on background threads.

One writer per frame uid at a time (:meth:`SavedFrames.lock`); other frames are written side by
side. :meth:`SavedFrames.save` writes a frame durably (:func:`history.frame_file.write_durably`)
unless its file exists. :meth:`SavedFrames.presave` starts that write on one of
:data:`PRESAVE_WORKERS` threads when a frame is frozen, before anyone clicks on it, at most
:data:`PRESAVE_PENDING` at a time; a presaved frame that no measurement used within
:data:`PRESAVE_KEEP_S` seconds is deleted (:meth:`SavedFrames.sweep`). The numbers behind these
are in docs/decisions/history-presave.md.
"""

from __future__ import annotations

import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from history import frame_file
from history.errors import SavedFrameUnreadable, StoreError, StoreFull
from history.frame_file import SUFFIX, TMP_SUFFIX, encode_frame, load_frame_file
from history.space import Space, is_full
from measure import Frame

PRESAVE_WORKERS = 2
PRESAVE_PENDING = 8
PRESAVE_KEEP_S = 600.0


def load_frame(path: Path) -> Frame:
    """Read a saved frame: a ``.frame`` file, or an ``.npz`` of earlier versions; raises
    :class:`SavedFrameUnreadable` naming the file."""
    try:
        return load_frame_file(path)
    except OSError as exc:
        raise SavedFrameUnreadable(f"cannot read saved frame {path}: {exc.strerror or exc}; the history entry needs this file") from exc
    except Exception as exc:  # zipfile.BadZipFile, KeyError, ValueError...: a damaged file, never a crash
        raise SavedFrameUnreadable(f"cannot read saved frame {path}: {exc}; the file is damaged") from exc


class SavedFrames:
    """The frame files in ``folder``; ``is_stored(uid)`` says whether the database has the frame's row."""

    def __init__(self, folder: Path, space: Space, is_stored: Callable[[str], bool]) -> None:
        self.folder = folder
        self.space = space
        self._is_stored = is_stored
        self._books = threading.Lock()  # never held across I/O
        self._locks: dict[str, threading.Lock] = {}
        self._presaving = 0
        self._presaved: dict[str, float] = {}  # uid -> when, for frames saved before any measurement
        self._pool = ThreadPoolExecutor(max_workers=PRESAVE_WORKERS, thread_name_prefix="depthruler-presave")

    def path(self, uid: str) -> Path:
        return self.folder / f"{uid}{SUFFIX}"

    def close(self) -> None:
        self._pool.shutdown(wait=True)

    @contextmanager
    def lock(self, uid: str) -> Iterator[None]:
        """Hold frame ``uid``: its file is written, or deleted, by one thread at a time."""
        with self._books:
            lock = self._locks.setdefault(uid, threading.Lock())
        with lock:
            yield
        with self._books:
            if self._locks.get(uid) is lock and not lock.locked():
                del self._locks[uid]

    def save(self, uid: str, frame: Frame) -> int:
        """Write ``frame`` as ``<uid>.frame`` durably unless it is there already (the caller holds
        :meth:`lock`); its size in bytes. Raises StoreFull on a full disk, StoreError otherwise."""
        path = self.path(uid)
        if path.exists():  # the rename is atomic: a file under this name is complete
            return path.stat().st_size
        short = self.space.shortage()
        if short:  # it might still fit, in the room kept for deleting and editing: leave that room
            raise StoreFull(f"frame {uid} not stored: {short}")
        data = encode_frame(frame)
        try:
            frame_file.write_durably(path, data)
        except OSError as exc:
            if is_full(exc):
                reason = f"the disk holding {self.folder} is full ({exc.strerror or exc}); free space there or lower --history-max-gb"
                self.space.failed(reason)
                raise StoreFull(f"frame {uid} not stored: {reason}") from None
            raise StoreError(f"cannot save frame {uid} to {path}: {exc.strerror or exc}") from exc
        self.space.saved(len(data))
        return len(data)

    def measured(self, uid: str) -> None:
        """Frame ``uid`` now has a measurement: it is no longer a presaved frame to sweep."""
        with self._books:
            self._presaved.pop(uid, None)

    def presave(self, uid: str, frame: Frame, refuse: bool = False) -> bool:
        """Start writing ``frame`` in the background; False, doing nothing, while :data:`PRESAVE_PENDING`
        presaves are queued or running, or when ``refuse`` (the disk is short)."""
        with self._books:
            if self._presaving >= PRESAVE_PENDING or refuse:
                return False
            self._presaving += 1
        self._pool.submit(self._presave, uid, frame)
        return True

    def _presave(self, uid: str, frame: Frame) -> None:
        try:
            with self.lock(uid):
                if not self._is_stored(uid) and not self.path(uid).exists():
                    self.save(uid, frame)
                    with self._books:
                        self._presaved[uid] = time.monotonic()
        except StoreError:
            pass  # the measurement, if one comes, writes the frame itself and reports the error
        finally:
            with self._books:
                self._presaving -= 1

    def sweep(self) -> None:
        """Delete presaved frames that no measurement used within :data:`PRESAVE_KEEP_S`."""
        now = time.monotonic()
        with self._books:
            old = [u for u, t in self._presaved.items() if now - t > PRESAVE_KEEP_S]
        for uid in old:
            with self.lock(uid):
                with self._books:
                    self._presaved.pop(uid, None)
                if not self._is_stored(uid):
                    self.path(uid).unlink(missing_ok=True)

    def clean_leftovers(self, known: set[str]) -> None:
        """Delete what a crash can leave: temporary files, and frame files not in ``known`` (the
        database's file names), whose row was never committed."""
        for p in self.folder.iterdir():
            stale = p.name.endswith((TMP_SUFFIX, ".tmp.npz"))
            orphan = p.suffix in (SUFFIX, ".npz") and p.name not in known
            if (stale or orphan) and p.is_file():
                p.unlink(missing_ok=True)

    def preview(self, file: str) -> np.ndarray:
        """The colour image of saved frame ``file`` decoded at 1/4 size (fast, for a thumbnail)."""
        path = self.folder / file
        if path.suffix == ".npz":
            return load_frame(path).image
        try:
            with zipfile.ZipFile(path) as zf:
                data = zf.read("color.jpg")
        except Exception as exc:  # noqa: BLE001 — a damaged file is an error answer, not a crash
            raise SavedFrameUnreadable(f"cannot read saved frame {path}: {exc}") from exc
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_REDUCED_COLOR_4)
        if image is None:
            raise SavedFrameUnreadable(f"the colour image in {path} cannot be decoded")
        return image
