"""Frames of the live stream: a bounded ring buffer with ids (the capture thread that fills it is in
:mod:`service.capture`).

A measurement names the id of the frame it was clicked on, so the live stream moving on never
changes the frame under a click; a frozen frame is kept out of eviction while any client holds it
(each freeze is a hold, each unfreeze drops one) and has used it within ``freeze_ttl_s``.
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

from measure import Frame

from service.frame_errors import FrameGone, FrameUnknown, NotAReplay, ReplayControlError, SeekOutOfRange, TooManyWaiters
from service.packed import PackedFrame

__all__ = ["FrameGone", "FrameRing", "FrameUnknown", "NotAReplay", "ReplayControlError", "RingFrame",
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

    def cached(self, key: str) -> bytes | None:
        """The encoding ``key`` if made already (no lock, no waiting: for the event loop)."""
        return self.cache.get(key)

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
        self.last_viewed = 0  # the newest frame id handed out as "latest"
        self.hold_before = hold_before
        self._held: tuple[int, list[RingFrame]] = (0, [])  # (frozen id, the frames just before it)
        self._cond = threading.Condition()

    def push(self, frame: Frame, *, frozen: bool = False, uid: str | None = None, cache: dict[str, bytes] | None = None) -> RingFrame:
        """Add ``frame`` as the newest; ``cache``: encodings made already, in the entry from the moment
        it can be seen."""
        packed = PackedFrame.pack(frame)  # outside the lock: readers of the ring need not wait for the packing
        with self._cond:
            fid = next(self._ids)
            self._next = fid + 1
            entry = RingFrame(id=fid, packed=packed, holds=int(frozen), touched=self._clock(), cache=dict(cache or {}))
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

    @property
    def followed(self) -> bool:
        """Whether the newest frame was handed out as "latest" (a page follows the stream, so it asks
        for the next one's image too)."""
        with self._cond:
            return self.last_viewed > 0 and self.last_viewed == self._next - 1

    def mark_viewed(self, fid: int) -> None:
        """Keep frame ``fid`` while it is among the last ``keep_viewed`` frames shown to a client."""
        with self._cond:
            self.last_viewed = max(self.last_viewed, fid)
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
