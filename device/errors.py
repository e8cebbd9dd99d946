"""Typed errors of every source; each message says what to plug in, install or fix."""


class SourceError(RuntimeError):
    """Base class of all source errors."""


class SourceNotFound(SourceError):
    """The named device, file or scene does not exist or cannot be opened."""


class SourceTimeout(SourceError):
    """No frame arrived within the timeout."""


class SourceDisconnected(SourceError):
    """The device went away mid-stream (cable pulled, XLink error); reopen to retry."""


class SourceEnded(SourceDisconnected):
    """A finite source (a recording played without loop) delivered its last frame. Reopening
    would start it over, so a live view stops here and keeps the last frame."""


class CalibrationError(SourceError):
    """Calibration is missing, unreadable or inconsistent."""


class RecordingError(SourceError):
    """A recording cannot be written or read; names the file and what to do."""
