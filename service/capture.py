"""The capture thread: reads frames from a source into the ring, and survives any source error (it
reports the state and message, closes the source and reopens it with exponential backoff)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from device import CalibrationError, Source, SourceEnded, SourceInfo, SourceTimeout
from measure import Frame

from service.frame_errors import NotAReplay, SeekOutOfRange
from service.frames import FrameRing
from service.provenance import RECORDED_KINDS, recorded_index
from service.render import LIVE_JPEG, encode_jpeg

__all__ = ["Capture", "FrameSink", "SourceFactory"]


class _Misconfigured(Exception):
    """The source factory failed: the spec or its configuration is wrong (its cause says how)."""


SourceFactory = Callable[[], Source]
FrameSink = Callable[[Frame], None]


class Capture:
    """Reads frames from a source into a :class:`FrameRing` on a daemon thread.

    States: "connecting" (first open), "streaming", "disconnected" (after an error, waiting to
    retry), "reconnecting" (reopening), "ended" (a finite source such as a replay without loop
    delivered its last frame: not reopened, which would start it over; the last frame stays
    measurable), "failed" (the source's configuration is wrong: its spec does not make a source,
    or its calibration cannot be read; reopening cannot help, so it is not retried), "stopped". A read that times out (:class:`SourceTimeout`) is counted and retried
    on the open source: for an OAK a reopen is a device reboot. Any other exception from the source
    (a :class:`SourceDisconnected`, or anything unexpected) is caught, its message kept for
    ``status()``, and the source reopened after a backoff that doubles from
    ``backoff_initial_s`` up to ``backoff_max_s``; it resets after a successful frame. A source's
    ``warnings`` list (a replay's skipped frames) shows in ``status()``.
    """

    def __init__(
        self,
        factory: SourceFactory,
        ring: FrameRing,
        *,
        spec: str = "",
        fps: float,
        backoff_initial_s: float,
        backoff_max_s: float,
        read_timeout_s: float = 2.0,
    ) -> None:
        self.factory = factory
        self.ring = ring
        self.spec = spec
        self.period_s = 1.0 / fps
        self.backoff_initial_s = backoff_initial_s
        self.backoff_max_s = backoff_max_s
        self.read_timeout_s = read_timeout_s
        self.sinks: list[FrameSink] = []
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._wake = threading.Event()
        self._reset()

    def _reset(self) -> None:
        """The state of a capture that has not read yet (at construction, and on :meth:`switch`)."""
        self._stop = threading.Event()
        self._state, self._message, self._info = "connecting", "", None
        self._frames, self._retries, self._timeouts = 0, 0, 0
        self._next_retry: float | None = None
        self._times: list[float] = []
        self._warnings: list[str] = []
        # replay control: paused, frames to deliver while paused, position to jump to, last index shown
        self._paused, self._steps = False, 0
        self._seek: int | None = None
        self._replay_index: int | None = None

    def switch(self, factory: SourceFactory, spec: str) -> None:
        """Read from another source from now on: the thread stops (closing the source) and starts again
        on ``factory``. Frames already in the ring, frozen ones included, stay."""
        self.stop()
        with self._lock:
            self.factory, self.spec = factory, spec
            self._reset()
        self.start()

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="depthruler-capture", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._set(state="stopped")

    def _set(self, **kw: Any) -> None:
        with self._lock:
            for k, v in kw.items():
                setattr(self, "_" + k, v)

    def status(self) -> dict[str, Any]:
        with self._lock:
            info = self._info
            times = list(self._times)
            fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 0.0
            retry_in = max(0.0, self._next_retry - time.monotonic()) if self._next_retry is not None else None
            return {
                "state": self._state,
                "message": self._message,
                "spec": self.spec,
                "kind": info.kind if info else "",
                "name": info.name if info else "",
                "serial": info.serial if info else "",
                "width": info.width if info else 0,
                "height": info.height if info else 0,
                "fps": info.fps if info else 0.0,
                # What the device does to depth before it arrives (the OAK's stereo post-processing).
                "depth": dict(info.extra["depth"]) if info and isinstance(info.extra.get("depth"), dict) else None,
                "measured_fps": round(fps, 2),
                "frames": self._frames,
                "retries": self._retries,
                "retry_in_s": retry_in,
                "replay": self._replay_status(info) if info and info.kind in RECORDED_KINDS else None,
                "timeouts": self._timeouts,
                "warnings": list(self._warnings)[-10:],
            }

    def _replay_status(self, info: SourceInfo) -> dict[str, Any]:
        path = str(info.extra.get("path", "") or "")
        replay = info.kind == "replay"
        return {
            "kind": info.kind,
            "paused": self._paused,
            "index": self._replay_index,
            "frames": int(info.extra.get("frames", 0) or 0),
            # a replay's folder name (its info.name is the recorded source's); a bag's or video's file name(s)
            "recording": path.rstrip("/").rsplit("/", 1)[-1] if replay else info.name,
            "recorded_source": info.name if replay else "",
        }

    def control(self, action: str, index: int | None = None) -> dict[str, Any]:
        """Drive a replay: "pause", "play", "step" (one frame while paused) or "seek" to frame ``index``
        (pauses and shows it). Raises :class:`NotAReplay` or :class:`SeekOutOfRange`."""
        with self._lock:
            info = self._info
            if info is None or info.kind not in RECORDED_KINDS:
                raise NotAReplay(f"the source {self.spec!r} is not a replay of a recording; pause, step and seek drive replays, "
                                 "bags and video files only")
            frames = int(info.extra.get("frames", 0) or 0)
            if action == "pause":
                self._paused = True
            elif action == "play":
                self._paused, self._steps = False, 0
            elif action == "step":
                self._paused, self._steps = True, self._steps + 1
            elif action == "seek":
                if index is None or not 0 <= index < frames:
                    raise SeekOutOfRange(f"seek needs an index in 0..{frames - 1} (the recording has {frames} frames), got {index}")
                self._paused, self._seek, self._steps = True, index, 1
            status = self._replay_status(info)
        self._wake.set()
        return status

    def _await_turn(self, src: Source) -> None:
        """While a replay is paused, block until a step or a seek asks for a frame (or stop)."""
        while not self._stop.is_set():
            with self._lock:
                if self._seek is not None:
                    src.seek(self._seek)  # type: ignore[attr-defined]  # every recorded kind has seek(i)
                    self._seek = None
                if not self._paused:
                    return
                if self._steps > 0:
                    self._steps -= 1
                    return
                self._wake.clear()
            self._wake.wait(0.2)

    @property
    def info(self) -> SourceInfo | None:
        with self._lock:
            return self._info

    def _run(self) -> None:
        backoff = self.backoff_initial_s
        first = True
        while not self._stop.is_set():
            src: Source | None = None
            try:
                self._set(state="connecting" if first else "reconnecting", next_retry=None)
                try:
                    src = self.factory()
                except Exception as exc:  # noqa: BLE001 — the spec itself is wrong: it will not work on a retry
                    raise _Misconfigured(exc) from exc
                src.open()
                self._set(info=src.info, warnings=getattr(src, "warnings", []))
                while not self._stop.is_set():
                    self._await_turn(src)
                    t0 = time.monotonic()
                    try:
                        frame = src.read(self.read_timeout_s)
                    except SourceTimeout as exc:
                        with self._lock:
                            self._timeouts += 1
                            self._message = f"SourceTimeout: {exc} (retrying)"
                        continue
                    self._deliver(frame, src.info)
                    backoff = self.backoff_initial_s
                    self._stop.wait(max(0.0, self.period_s - (time.monotonic() - t0)))
            except SourceEnded as exc:
                self._set(state="ended", message=str(exc), next_retry=None)
                return
            except (_Misconfigured, CalibrationError) as exc:
                cause = exc.__cause__ if isinstance(exc, _Misconfigured) and exc.__cause__ else exc
                message = f"{type(cause).__name__}: {cause}; fix the source's configuration and restart the server"
                self._set(state="failed", message=message, next_retry=None)
                return
            except Exception as exc:  # noqa: BLE001 — any source failure must leave the service up
                message = f"{type(exc).__name__}: {exc}"
                with self._lock:
                    self._state = "disconnected"
                    self._message = message
                    self._retries += 1
                    self._next_retry = time.monotonic() + backoff
            finally:
                first = False
                if src is not None:
                    try:
                        src.close()
                    except Exception:  # noqa: BLE001 — closing a dead device may fail too; we reopen anyway
                        pass
            if self._stop.is_set():
                break
            self._stop.wait(backoff)
            backoff = min(self.backoff_max_s, backoff * 2)

    def _deliver(self, frame: Frame, info: SourceInfo) -> None:
        # A page follows every frame: its JPEG is made before the frame can be seen, so the live view's
        # request never finds the frame without it (and waits for an encoding behind other threads).
        cache = {LIVE_JPEG: encode_jpeg(frame.image)} if self.ring.followed else None
        self.ring.push(frame, cache=cache)
        now = time.monotonic()
        with self._lock:
            self._state = "streaming"
            self._message = ""
            self._info = info
            self._frames += 1
            self._times = (self._times + [now])[-30:]
            self._replay_index = recorded_index(frame)
        for sink in list(self.sinks):
            sink(frame)
