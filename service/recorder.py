"""Recording the live stream from the API: one writer at a time, fed by the capture thread.

Every recording goes into one folder, the server's recordings root (``--recordings``); a client
names at most a plain folder inside it (checked by :class:`service.schemas.RecordingIn`, and again
here), never a path, and never a symbolic link that leads out of it. A write that fails (a full
disk) stops the recording and keeps the reason for ``status()`` and the health answer.
Each refusal is a :class:`RecorderError` subclass; ``service.errors`` gives each its HTTP status.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

from measure import Frame

from service.capture import Capture
from service.schemas import is_plain_name


class RecorderError(RuntimeError):
    """A recording cannot be started or stopped; the message says what to do."""


class RecordingUnavailable(RecorderError):
    """This build cannot record (the recording format's module is missing)."""


class NotStreaming(RecorderError):
    """The source has not delivered a frame yet."""


class AlreadyRecording(RecorderError):
    """A recording runs already: one at a time."""


class NotRecording(RecorderError):
    """Stop asked while nothing records."""


class BadRecordingName(RecorderError):
    """The name is not a plain folder inside the recordings root (or leads out of it)."""


class CannotRecord(RecorderError):
    """The recording's folder cannot be created or written."""


class Recorder:
    """Writes the live frames to a recording (device.formats.recording.RecordingWriter) while started."""

    def __init__(self, capture: Capture, root: Path) -> None:
        self.capture = capture
        self.root = Path(root).resolve()
        self._lock = threading.Lock()
        self._writer: Any = None
        self._path: Path | None = None
        self._frames = 0
        self._error = ""

    def status(self) -> dict[str, Any]:
        with self._lock:
            return {
                "active": self._writer is not None,
                "path": str(self._path) if self._path else None,
                "frames": self._frames,
                "error": self._error,
            }

    def start(self, out: str | None) -> dict[str, Any]:
        try:
            from device.formats.recording import RecordingWriter
        except ImportError as exc:
            raise RecordingUnavailable(f"recording is not available in this build ({exc})") from exc
        info = self.capture.info
        if info is None:
            raise NotStreaming("the source has not delivered a frame yet; start recording once it streams")
        path = self.root / (out or time.strftime("%Y%m%d-%H%M%S"))
        if path.parent != self.root or not is_plain_name(path.name):
            raise BadRecordingName(f"out must be a plain folder name inside {self.root} (got {out!r})")
        if path.is_symlink() or path.resolve().parent != self.root:
            raise BadRecordingName(f"{path} is a link that leads out of {self.root}; name another folder")
        with self._lock:
            if self._writer is not None:
                raise AlreadyRecording(f"already recording to {self._path}; stop it first")
            try:
                self.root.mkdir(parents=True, exist_ok=True)
                self._writer = RecordingWriter(path, info)
            except Exception as exc:  # noqa: BLE001 — RecordingError or OSError: report, don't crash
                raise CannotRecord(f"cannot record to {path}: {exc}") from exc
            self._path, self._frames, self._error = path, 0, ""
        self.capture.sinks.append(self._write)
        return self.status()

    def stop(self) -> dict[str, Any]:
        with self._lock:
            if self._writer is None:
                raise NotRecording("not recording; start a recording first")
            self._close()
        return self.status()

    def _close(self) -> None:
        if self._write in self.capture.sinks:
            self.capture.sinks.remove(self._write)
        writer, self._writer = self._writer, None
        try:
            writer.close()
        except Exception as exc:  # noqa: BLE001
            self._error = f"closing the recording failed: {exc}"

    def _write(self, frame: Frame) -> None:
        with self._lock:
            if self._writer is None:
                return
            try:
                self._writer.write(frame)
                self._frames += 1
            except Exception as exc:  # noqa: BLE001 — a full disk must stop the recording, not the stream
                self._error = f"recording stopped: {exc}"
                self._close()
