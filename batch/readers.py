"""Frame readers of a batch worker: a source opened once per process and read by frame index.

A recording (``replay:DIR`` without options) and the service history are read at random (a frame
costs only its own files); any other spec is read in order, frame ``i`` being the ``i``-th
``read()`` after opening. A worker keeps the last :data:`READER_CACHE` sources open, so the next
group of the same recording does not open it again.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import Protocol

from measure import Frame

from batch.tasks import TaskError, source_kind

READER_CACHE = 2  # open sources kept per worker process


class FrameReader(Protocol):
    def frame(self, key: int | str) -> Frame: ...

    def close(self) -> None: ...


class RecordingFrames:
    """A recording folder, read by index (a frame costs only its own files)."""

    def __init__(self, path: str) -> None:
        from batch.remote import is_url, local_recording
        from device.formats.recording import open_recording

        self.rec = open_recording(local_recording(path) if is_url(path) else path)

    def frame(self, key: int | str) -> Frame:
        i = int(key)
        if not 0 <= i < len(self.rec):
            raise TaskError(f"frame {i} is not in {self.rec.path}: it holds {len(self.rec)} complete frames (0-{len(self.rec) - 1})")
        return self.rec.frame(i)

    def close(self) -> None:
        pass


class SequentialFrames:
    """Any source spec read in order: frame ``i`` is the ``i``-th ``read()`` after opening. Asking for
    an earlier frame than the last one reopens the source (groups ask in ascending order)."""

    def __init__(self, spec: str) -> None:
        from device import make_source

        self.spec = spec
        self.src = make_source(spec)
        self.src.open()
        self.pos = -1
        self.last: Frame | None = None

    def frame(self, key: int | str) -> Frame:
        from device import SourceEnded

        i = int(key)
        if i < self.pos:
            self.src.close()
            self.src.open()
            self.pos, self.last = -1, None
        while self.pos < i:
            try:
                self.last = self.src.read(timeout_s=60.0)
            except SourceEnded:
                raise TaskError(f"frame {i} is not in {self.spec}: it ended after {self.pos + 1} frames") from None
            self.pos += 1
        assert self.last is not None
        return self.last

    def close(self) -> None:
        self.src.close()


def open_reader(source: str) -> FrameReader:
    """A reader of ``source`` (a task's normalised spec), random access where the kind allows it."""
    kind = source_kind(source)
    if kind == "history":
        from batch.history import HistoryFrames

        return HistoryFrames(Path(source.partition(":")[2]))
    if kind == "replay":
        from device import SourceSpec

        spec = SourceSpec.parse(source)
        if not spec.params:  # replay options (start, loop) change what index i means: read in order then
            return RecordingFrames(spec.target)
        from batch.remote import is_url, local_recording

        if is_url(spec.target):
            query = source.partition("?")[2]
            return SequentialFrames(f"replay:{local_recording(spec.target)}?{query}")
    return SequentialFrames(source)


_readers: OrderedDict[str, FrameReader] = OrderedDict()


def reader_for(source: str) -> FrameReader:
    """This process's open reader of ``source``; the least recently used one closes past the cache size."""
    reader = _readers.pop(source, None)
    if reader is None:
        reader = open_reader(source)
    _readers[source] = reader
    while len(_readers) > READER_CACHE:
        _, old = _readers.popitem(last=False)
        old.close()
    return reader


def close_readers() -> None:
    """Close every source this process keeps open."""
    while _readers:
        _readers.popitem()[1].close()
