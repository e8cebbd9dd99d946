"""What the service-load bench runs beside its clients: a viewer following the live stream, and a
prober (in a process of its own) timing the live frame and health."""

from __future__ import annotations

import multiprocessing
import threading
import time

import httpx
import numpy as np


class Viewer(threading.Thread):
    """Follows the live stream like the page: long-poll for the next frame, then fetch its image."""

    def __init__(self, base: str) -> None:
        super().__init__(daemon=True)
        self.base, self.stop, self.shown = base, threading.Event(), 0

    def run(self) -> None:
        after, image = 0, "color.jpg"
        with httpx.Client(base_url=self.base, timeout=30) as http:
            while not self.stop.is_set():
                r = http.get("/api/frames/latest", params={"after": after, "wait": 2})
                if r.status_code != 200:
                    continue
                after = r.json()["id"]
                img = http.get(f"/api/frames/{after}/{image}")
                if img.status_code == 404 and image == "color.jpg":
                    image = "color.png"  # a server without the JPEG route
                    img = http.get(f"/api/frames/{after}/{image}")
                self.shown += img.status_code == 200


def _probe(base: str, every_s: float, stop, out) -> None:
    """The prober's loop (in a process of its own: see :class:`Prober`); sends (live_ms, health_ms)."""
    live_ms: list[float] = []
    health_ms: list[float] = []
    with httpx.Client(base_url=base, timeout=120) as http:
        while not stop.wait(every_s):
            t0 = time.perf_counter()
            r = http.get("/api/frames/latest")
            if r.status_code == 200:
                img = http.get(f"/api/frames/{r.json()['id']}/color.jpg")
                if img.status_code == 200:
                    live_ms.append((time.perf_counter() - t0) * 1e3)
            t0 = time.perf_counter()
            if http.get("/api/health").status_code == 200:
                health_ms.append((time.perf_counter() - t0) * 1e3)
            if out.poll():  # asked for the figures so far
                out.recv()
                out.send((len(live_ms), len(health_ms)))
    out.send((live_ms, health_ms))


class Prober:
    """What a person feels while others load the service: every ``every_s``, the live frame (`GET
    /api/frames/latest` without waiting, then its JPEG) and `GET /api/health`, each timed (ms).

    It runs in a process of its own: in the bench's process its requests would wait for the
    interpreter lock behind the 32 client threads, and their time would count as the server's."""

    def __init__(self, base: str, every_s: float = 0.1) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._stop = ctx.Event()
        self._pipe, child = ctx.Pipe()
        self._proc = ctx.Process(target=_probe, args=(base, every_s, self._stop, child), daemon=True)
        self.live_ms: list[float] = []
        self.health_ms: list[float] = []

    def start(self) -> None:
        self._proc.start()

    def counts(self) -> tuple[int, int]:
        """How many live-frame and health probes were answered so far."""
        self._pipe.send("counts")
        return self._pipe.recv()

    def finish(self) -> None:
        """Stop the probes and collect their times into ``live_ms`` and ``health_ms``."""
        self._stop.set()
        msg = self._pipe.recv()
        while not isinstance(msg[0], list):  # a reply to a counts() still in the pipe
            msg = self._pipe.recv()
        self.live_ms, self.health_ms = msg
        self._proc.join(60)


def pct(a: list[float] | np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) if len(a) else float("nan")
