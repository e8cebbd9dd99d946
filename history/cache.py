"""What the store keeps in memory, derived from the database: encoded slim records and thumbnails.

The history list is served from slim records (no per-sample arrays) encoded once per
measurement, at most :data:`SLIM_CACHE` of them; thumbnails are drawn on first request and kept,
the least recently used beyond :data:`THUMB_CACHE` dropped. Both are derived data (never written
to the database: a commit per thumbnail would make measurements wait for the write lock), dropped
when their measurement changes. The numbers behind the sizes are in docs/decisions/history-presave.md.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

SLIM_CACHE = 10_000
THUMB_CACHE = 512


class RecordCache:
    """Thread-safe; ``changes`` counts the changes, so an encoding made across one is not kept."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._slim: dict[int, bytes] = {}
        self._thumbs: OrderedDict[int, bytes] = OrderedDict()
        self._changes = 0

    @property
    def changes(self) -> int:
        with self._lock:
            return self._changes

    def slim(self, ids: list[int]) -> list[bytes | None]:
        with self._lock:
            return [self._slim.get(i) for i in ids]

    def keep_slim(self, fresh: dict[int, bytes], changes: int) -> None:
        """Keep ``fresh`` encodings, made when :attr:`changes` was ``changes``, unless something changed since."""
        with self._lock:
            if self._changes != changes:
                return
            self._slim |= fresh
            for old in list(self._slim)[: max(0, len(self._slim) - SLIM_CACHE)]:
                del self._slim[old]

    def changed(self, mid: int) -> None:
        """Measurement ``mid`` was changed or deleted (after the write): drop what was derived from it."""
        with self._lock:
            self._changes += 1
            self._slim.pop(mid, None)
            self._thumbs.pop(mid, None)

    def keep_thumb(self, mid: int, thumb: bytes) -> None:
        with self._lock:
            self._thumbs[mid] = thumb
            while len(self._thumbs) > THUMB_CACHE:
                self._thumbs.popitem(last=False)

    def thumb(self, mid: int) -> bytes | None:
        with self._lock:
            data = self._thumbs.get(mid)
            if data is not None:
                self._thumbs.move_to_end(mid)
            return data
