"""What the routers share: the frame ring, the capture thread, the history store, the recorder, the
measurement workers and the live view's image thread.

One :class:`ServiceState` per app, built by ``create_app`` and handed to each router through the
dependencies of :mod:`service.deps`, so a route names what it uses instead of reaching into globals.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from device import Source
from history.store import Store

from service.capture import Capture
from service.frames import FrameRing
from service.recorder import Recorder
from service.workers import MeasurePool


@dataclass
class ServiceState:
    ring: FrameRing
    capture: Capture
    store: Store
    recorder: Recorder
    measures: MeasurePool = field(default_factory=MeasurePool)
    started: float = field(default_factory=time.time)
    home: tuple[Callable[[], Source], str] | None = None  # the server's own source (factory, spec)
    kernels: str = ""  # where the measuring kernels come from, once the app's start chose them (health)
    # a live frame's JPEG is made once, never queued behind the routes on the general thread pool: one thread
    live_images: ThreadPoolExecutor = field(default_factory=lambda: ThreadPoolExecutor(1, thread_name_prefix="live-image"))
