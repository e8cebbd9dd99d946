"""Playing a finite capture (a recording, a bag) in order: where the next frame is, looping or ending as
asked, and damaged frames skipped and counted per pass.

Steps of :meth:`Playback.next`: at the end of the frames, end (:class:`EndOfRecording`, naming the frames
skipped in that pass) or, with ``loop``, start a new pass at frame 0; wait for the frame when realtime;
read it; a frame that raises :class:`RecordingError` is skipped, counted in the pass and the next one is
tried in the same loop (no recursion, so thousands of damaged frames cost no stack). Only when every frame
has been tried in a row and none could be read does it raise :class:`NoReadableFrame`, which ends the
source: reopening would fail the same way, so a live view must not reconnect to it.
"""

from __future__ import annotations

from collections.abc import Callable

from measure import Frame

from device.errors import RecordingError
from device.formats.recording.format import EndOfRecording
from device.pacing import Pacer

MAX_WARNINGS = 50  # skip messages kept (the newest); the counts cover all


class NoReadableFrame(EndOfRecording, RecordingError):
    """Every frame of a finite capture was tried and none could be read."""


class Playback:
    """The position in ``n`` frames played from ``start``; ``skipped`` maps the frames skipped in the current
    pass to why, ``skipped_total`` counts every skip, ``passes`` the passes begun (1 on the first).
    ``warnings`` is updated in place (a caller may hold it) with the newest skip messages."""

    def __init__(self, n: int, *, what: str, loop: bool = False, realtime: bool = False, start: int = 0,
                 pacer: Pacer | None = None, loop_hint: str = "") -> None:
        self.n, self.what, self.loop, self.realtime = n, what, loop, realtime
        self.pacer = pacer or Pacer()
        self.loop_hint = loop_hint
        self.pos = start
        self.passes = 1
        self.delivered = 0  # frames delivered in the current pass
        self.skipped: dict[int, str] = {}
        self.skipped_total = 0
        self.warnings: list[str] = []

    def seek(self, i: int) -> None:
        """Make frame ``i`` the next one; the pace restarts from it."""
        if not 0 <= i < self.n:
            raise IndexError(f"frame {i} is out of range: {self.what} has {self.n} frames")
        self.pos = i
        self.pacer.restart()

    def _skip_note(self) -> str:
        if not self.skipped:
            return ""
        listed = ", ".join(str(i) for i in sorted(self.skipped)[:10]) + (", ..." if len(self.skipped) > 10 else "")
        return f" ({len(self.skipped)} damaged frame(s) skipped in this pass: {listed})"

    def next(self, read: Callable[[int], Frame], timeout_s: float) -> Frame:
        """The next frame by ``read(i)``; see the module docstring for ending, looping and skipping."""
        failed_in_a_row = 0
        last: RecordingError | None = None
        while True:
            if self.pos >= self.n:
                if not self.loop:
                    if self.delivered == 0 and self.skipped and last is not None:
                        raise NoReadableFrame(f"no frame of {self.what} can be read{self._skip_note()}; last: {last}")
                    raise EndOfRecording(f"{self.what} reached its end after {self.n} frames{self._skip_note()}"
                                         + (f"; {self.loop_hint}" if self.loop_hint else ""))
                self.pos, self.passes, self.delivered = 0, self.passes + 1, 0
                self.skipped = {}
                self.pacer.restart()
            i = self.pos
            if self.realtime:
                self.pacer.wait_for(i, timeout_s, self.what)
            self.pos += 1
            try:
                frame = read(i)
            except RecordingError as exc:
                last = exc
                failed_in_a_row += 1
                self.skipped[i] = str(exc)
                self.skipped_total += 1
                self.warnings.append(f"{exc}; frame {i} skipped")
                del self.warnings[:-MAX_WARNINGS]
                if failed_in_a_row >= self.n:
                    raise NoReadableFrame(f"no frame of {self.what} can be read: all {self.n} were tried and "
                                          f"failed; last: {exc}") from exc
                continue
            self.delivered += 1
            return frame
