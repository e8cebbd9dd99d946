"""The pace of a played-back capture (a recording, a bag): frame ``i`` is due ``offsets[i] / speed``
seconds after the frame a cycle started from, as it was captured."""

from __future__ import annotations

import time

import numpy as np

from device.errors import SourceTimeout


class Pacer:
    """When each frame of a capture is due; ``restart`` makes the next frame waited for the new start."""

    def __init__(self, offsets_s: np.ndarray | None = None, speed: float = 1.0) -> None:
        self.offsets_s = np.zeros(0) if offsets_s is None else np.asarray(offsets_s, np.float64)
        self.speed = speed
        self._start: float | None = None

    def restart(self) -> None:
        self._start = None

    def wait_for(self, i: int, timeout_s: float, what: str) -> None:
        """Sleep until frame ``i`` is due; a frame due after ``timeout_s`` raises SourceTimeout (after
        that timeout), as a live source with no frame yet would."""
        now = time.monotonic()
        if self._start is None:
            self._start = now - self.offsets_s[i] / self.speed
        wait = self._start + self.offsets_s[i] / self.speed - now
        if wait > timeout_s:
            time.sleep(max(timeout_s, 0.0))
            raise SourceTimeout(f"the next frame of {what} is due in {wait:.2f} s, after the {timeout_s} s timeout")
        if wait > 0:
            time.sleep(wait)
