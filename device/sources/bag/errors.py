"""The bag source's typed errors (subclasses of :class:`device.errors.RecordingError`)."""

from __future__ import annotations

from device.errors import RecordingError, SourceNotFound

class BagError(RecordingError):
    """A bag cannot be read as frames; the message names the file or topic and what to do."""


class BagNotFound(BagError, SourceNotFound):
    """The path is not there or is no bag."""


class BagLayoutError(BagError):
    """No known topic layout in the bag (and no topics were named); the message lists the image topics."""
