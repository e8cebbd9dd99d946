"""Frames of the live stream: a bounded ring buffer with ids, and the capture thread that fills it.

A measurement names the id of the frame it was clicked on, so the live stream moving on never
changes the frame under a click; a frozen frame is kept out of eviction while any client holds it
(each freeze is a hold, each unfreeze drops one) and has used it within ``freeze_ttl_s``.
The capture thread survives any source error: it reports the state and message, closes the
source and reopens it with exponential backoff.
"""

from __future__ import annotations

import asyncio
import itertools
import threading
import time
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from device import CalibrationError, Source, SourceEnded, SourceInfo, SourceTimeout
from measure import Frame

from service.frame_errors import FrameGone, FrameUnknown, NotAReplay, ReplayControlError, SeekOutOfRange, TooManyWaiters
from service.packed import PackedFrame
from service.provenance import RECORDED_KINDS, recorded_index

__all__ = ["Capture", "FrameGone", "FrameRing", "FrameUnknown", "NotAReplay", "ReplayControlError", "RingFrame",
           "SeekOutOfRange", "TooManyWaiters"]  # the errors live in service.frame_errors; named here as before


@dataclass
class RingFrame:
    """One buffered frame: its id, a uuid that names it in storage, and cached encodings."""

    id: int
    packed: PackedFrame  # the frame's arrays in as few bytes as give them back exactly
    uid: str = field(default_factory=lambda: uuid.uuid4().hex)
    received: float = field(default_factory=time.time)
    holds: int = 0  # clients that froze it and did not unfreeze it yet
    touched: float = 0.0  # the ring's clock when a client last froze or asked for it
    cache: dict[str, bytes] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def frozen(self) -> bool:
        return self.holds > 0

    @property
    def frame(self) -> Frame:
        return self.packed.unpack()

    def encoded(self, key: str, encode: Callable[[Any], bytes], *, image_only: bool = False) -> bytes:
        """``encode(frame)`` computed once per frame (the page polls the same frame repeatedly);
        ``image_only``: ``encode`` reads only ``.image``, handed the packed frame (nothing unpacked)."""
        with self.lock:
            if key not in self.cache:
                self.cache[key] = encode(self.packed if image_only else self.frame)
            return self.cache[key]


class FrameRing:
    """Bounded, thread-safe buffer of frames keyed by increasing ids.

    At most ``capacity`` unfrozen frames are kept (oldest evicted first). A frozen frame is held by
    reference: every freeze adds a hold and every unfreeze drops one, so one client releasing a frame
    never takes it from another that froze it too; a frame whose holders have not frozen or asked for
    it for ``freeze_ttl_s`` (a page closed without unfreezing) is released. At most ``max_frozen``
    frames are frozen (a memory bound): freezing one more releases the least recently used.
    Eviction passes over the last ``keep_viewed`` frames handed out as "latest": a page shows such a
    frame and may freeze it a moment later, when a fast source with a small ring would have evicted
    it already (30 fps into 4 frames leaves 0.13 s, less than a click). At most ``capacity +
    keep_viewed`` unfrozen frames are held in the ring. Freezing a frame also keeps up to
    ``hold_before`` frames received just before it (the newest freeze's only; ``before`` hands them
    out, ``get`` does not), so that a measurement over several frames of a still scene can use them
    after the stream moved on.
    """

    def __init__(
        self, capacity: int = 32, max_frozen: int = 64, keep_viewed: int = 8, max_waiters: int = 64, hold_before: int = 29,
        freeze_ttl_s: float = 60.0, clock: Callable[[], float] = time.monotonic,
    ) -> None:  # fmt: skip
        if capacity < 1 or max_frozen < 1 or max_waiters < 1:
            raise ValueError(
                f"ring capacity ({capacity}), max_frozen ({max_frozen}) and max_waiters ({max_waiters}) must be at least 1"
            )
        self.capacity = capacity
        self.max_frozen = max_frozen
        self.max_waiters = max_waiters
        self.freeze_ttl_s = freeze_ttl_s
        self._clock = clock
        self._wakers: set[Callable[[], None]] = set()
        self._frames: OrderedDict[int, RingFrame] = OrderedDict()
        self._ids = itertools.count(1)
        self._next = 1
        self._viewed: deque[int] = deque(maxlen=keep_viewed)
        self.hold_before = hold_before
        self._held: tuple[int, list[RingFrame]] = (0, [])  # (frozen id, the frames just before it)
        self._cond = threading.Condition()

    def push(self, frame: Frame, *, frozen: bool = False, uid: str | None = None) -> RingFrame:
        packed = PackedFrame.pack(frame)  # outside the lock: readers of the ring need not wait for the packing
        with self._cond:
            fid = next(self._ids)
            self._next = fid + 1
            entry = RingFrame(id=fid, packed=packed, holds=int(frozen), touched=self._clock())
            if uid:
                entry.uid = uid
            self._frames[fid] = entry
            if frozen:
                self._limit_frozen(keep=fid)
            self._expire()
            self._evict()
            self._cond.notify_all()
            for wake in list(self._wakers):
                wake()
            return entry

    def _evict(self) -> None:
        live = [fid for fid, e in self._frames.items() if not e.frozen]
        excess = len(live) - self.capacity
        newest = live[-1] if live else None  # never the frame just pushed: "latest" must move on
        for fid in [fid for fid in live if fid not in self._viewed and fid != newest][: max(0, excess)]:
            del self._frames[fid]

    def _limit_frozen(self, keep: int) -> None:
        frozen = sorted((e.touched, fid) for fid, e in self._frames.items() if e.frozen and fid != keep)
        for _, fid in frozen[: max(0, len(frozen) + 1 - self.max_frozen)]:
            self._frames[fid].holds = 0

    def _expire(self) -> None:
        """Release the frozen frames nobody froze or asked for within ``freeze_ttl_s``."""
        stale = self._clock() - self.freeze_ttl_s
        for e in self._frames.values():
            if e.frozen and e.touched < stale:
                e.holds = 0

    def get(self, fid: int) -> RingFrame:
        """Frame ``fid``; asking for a frozen frame keeps it for another ``freeze_ttl_s``."""
        with self._cond:
            entry = self._frames.get(fid)
            if entry is not None:
                entry.touched = self._clock()
                return entry
            if 1 <= fid < self._next:
                raise FrameGone(
                    f"frame {fid} was evicted from the ring buffer (it keeps the last {self.capacity} frames); "
                    "freeze a frame before measuring on it, or take the latest frame"
                )
            raise FrameUnknown(f"frame {fid} does not exist yet; the latest id is {self._next - 1}")

    def find(self, uid: str) -> RingFrame | None:
        """The frame stored as ``uid`` if the ring still holds it (a thumbnail drawn from memory)."""
        with self._cond:
            return next((e for e in reversed(self._frames.values()) if e.uid == uid), None)

    def latest(self) -> RingFrame | None:
        with self._cond:
            return self._frames[next(reversed(self._frames))] if self._frames else None

    def wait_latest(self, after: int = 0, timeout_s: float = 5.0) -> RingFrame | None:
        """The newest frame with an id above ``after``, waiting up to ``timeout_s`` for it."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                entry = self._frames[next(reversed(self._frames))] if self._frames else None
                if entry is not None and entry.id > after:
                    return entry
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)

    def mark_viewed(self, fid: int) -> None:
        """Keep frame ``fid`` while it is among the last ``keep_viewed`` frames shown to a client."""
        with self._cond:
            if fid in self._frames and fid not in self._viewed:
                self._viewed.append(fid)
                self._evict()
    @property
    def waiters(self) -> int:
        """Long-polls waiting in :meth:`wait_latest_async` now."""
        with self._cond:
            return len(self._wakers)

    async def wait_latest_async(self, after: int = 0, timeout_s: float = 5.0) -> RingFrame | None:
        """:meth:`wait_latest` on the event loop: a waiting client holds no worker thread, so any
        number of long-polls (up to ``max_waiters``, then :class:`TooManyWaiters`) cannot starve
        the other routes."""
        loop = asyncio.get_running_loop()
        event = asyncio.Event()

        def wake() -> None:
            try:
                loop.call_soon_threadsafe(event.set)
            except RuntimeError:  # the loop closed while a frame arrived: nobody is waiting any more
                pass

        with self._cond:
            if len(self._wakers) >= self.max_waiters:
                raise TooManyWaiters(f"{len(self._wakers)} clients are already waiting for a frame; retry in a second")
            self._wakers.add(wake)
        deadline = loop.time() + timeout_s
        try:
            while True:
                event.clear()  # before looking, so a frame pushed after the look still wakes us
                entry = self.latest()
                if entry is not None and entry.id > after:
                    return entry
                left = deadline - loop.time()
                if left <= 0:
                    return None
                try:
                    await asyncio.wait_for(event.wait(), left)
                except asyncio.TimeoutError:
                    pass
        finally:
            with self._cond:
                self._wakers.discard(wake)

    def freeze(self, fid: int, frozen: bool = True) -> RingFrame:
        with self._cond:
            entry = self.get(fid)
            entry.holds = entry.holds + 1 if frozen else max(0, entry.holds - 1)
            if frozen:
                self._held = (fid, self._before(fid, self.hold_before))
                self._limit_frozen(keep=fid)
            elif not entry.frozen:
                if self._held[0] == fid:
                    self._held = (0, [])
                self._evict()
            return entry

    def _before(self, fid: int, n: int) -> list[RingFrame]:
        held = self._held[1] if self._held[0] == fid else []
        older = {e.id: e for e in held} | {i: e for i, e in self._frames.items() if i < fid}
        return [older[i] for i in sorted(older, reverse=True)[:n]]

    def before(self, fid: int, n: int) -> list[RingFrame]:
        """Up to ``n`` frames received just before frame ``fid`` that show the same camera (size,
        intrinsics, baseline, source): newest first, stopping at the first that does not."""
        with self._cond:
            ref = self.get(fid).packed
            out = []
            for e in self._before(fid, n):
                f = e.packed
                if (f.shape != ref.shape or f.camera != ref.camera or f.baseline_m != ref.baseline_m or f.doffs != ref.doffs
                        or f.meta.get("source") != ref.meta.get("source")):
                    break
                out.append(e)
            return out

    def __len__(self) -> int:
        with self._cond:
            return len(self._frames)

    @property
    def nbytes(self) -> int:
        """Bytes of the frames' arrays and cached encodings the ring holds now."""
        with self._cond:
            return sum(e.packed.nbytes + sum(map(len, e.cache.values())) for e in self._frames.values())

    @property
    def frozen_ids(self) -> list[int]:
        with self._cond:
            return [fid for fid, e in self._frames.items() if e.frozen]


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
        self.ring.push(frame)
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
