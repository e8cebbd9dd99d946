"""What the frame ring and the capture refuse; :mod:`service.errors` gives each its HTTP status."""

from __future__ import annotations


class FrameGone(KeyError):
    """The frame id was evicted from the ring buffer (HTTP 410)."""


class FrameUnknown(KeyError):
    """The frame id was never issued (HTTP 404)."""


class NoConfidence(LookupError):
    """The frame's source gives no confidence map (``Frame.confidence`` is None) (HTTP 404)."""


class ReplayControlError(ValueError):
    """Pause, play, step or seek cannot be done."""


class NotAReplay(ReplayControlError):
    """Pause, play, step or seek asked of a source that is no replay (HTTP 409)."""


class SeekOutOfRange(ReplayControlError):
    """A seek to an index outside the replay (HTTP 422)."""


class TooManyWaiters(RuntimeError):
    """More long-polls are waiting than the ring allows (HTTP 429)."""
