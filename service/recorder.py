"""Recording the live stream from the API: one writer at a time, fed by the capture thread.

Every recording goes into one folder, the server's recordings root (``--recordings``); a client
names at most a plain folder inside it (checked by :class:`service.schemas.RecordingIn`, and again
here), never a path."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

from fastapi import HTTPException

from measure import Frame

from service.frames import Capture
from service.schemas import PLAIN_NAME


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
            raise HTTPException(503, f"recording is not available in this build ({exc})") from exc
        info = self.capture.info
        if info is None:
            raise HTTPException(409, "the source has not delivered a frame yet; start recording once it streams")
        path = self.root / (out or time.strftime("%Y%m%d-%H%M%S"))
        if path.parent != self.root or not PLAIN_NAME.match(path.name):
            raise HTTPException(422, f"out must be a plain folder name inside {self.root} (got {out!r})")
        with self._lock:
            if self._writer is not None:
                raise HTTPException(409, f"already recording to {self._path}; stop it first")
            try:
                self.root.mkdir(parents=True, exist_ok=True)
                self._writer = RecordingWriter(path, info)
            except Exception as exc:  # noqa: BLE001 — RecordingError or OSError: report, don't crash
                raise HTTPException(400, f"cannot record to {path}: {exc}") from exc
            self._path, self._frames, self._error = path, 0, ""
        self.capture.sinks.append(self._write)
        return self.status()

    def stop(self) -> dict[str, Any]:
        with self._lock:
            if self._writer is None:
                raise HTTPException(409, "not recording; start a recording first")
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
