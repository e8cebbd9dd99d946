"""The history's errors: each failure its own type, each message naming the file or id and what to do.

``service.errors`` maps each class to one HTTP status; nothing here knows about HTTP.
"""

from __future__ import annotations


class StoreError(RuntimeError):
    """The history database or a saved frame cannot be written or read; nothing was stored."""


class StoreFull(StoreError):
    """The disk holding the history is full: the measurement was not stored."""


class SavedFrameUnreadable(StoreError):
    """A saved frame file exists but cannot be read (damaged, or of a format this version does not read)."""


class MeasurementUnknown(LookupError):
    """No measurement has this id (never stored, or deleted)."""


class FrameNotSaved(LookupError):
    """The frame of a measurement is not among the saved frames (lost in a crash before its row, or never saved)."""


class FrameDropped(FrameNotSaved):
    """The frame of a measurement was deleted by the history's size cap; its numbers are kept."""


class HistoryUnreadable(StoreError):
    """A file given as a history database is missing or is not a depthruler history database."""
