"""A recording played back as a Source (``replay:DIR?loop=1&realtime=1&speed=1&start=0``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from measure import Frame, check_options, option

from device import configs
from device.base import SourceBase, SourceInfo, SourceSpec
from device.errors import RecordingError, SourceError
from device.pacing import Pacer
from device.formats.recording.format import FRAMES, RecordingNotFound
from device.formats.recording.playback import Playback
from device.formats.recording.reader import Recording, open_recording

# ---------------------------------------------------------------------------------------------
# replay as a Source


@dataclass(frozen=True)
class ReplayConfig:
    """A recording played back: each field's spelling, bounds and help are in its metadata."""

    path: Path = option(target=True, key="path", example="recordings/example", help="the recording folder")
    loop: bool = option(False, help="start again at the end")
    realtime: bool = option(False, help="pace frames by their recorded timestamps instead of as fast as read")
    speed: float = option(1.0, min=0.0, min_open=True, help="playback speed with realtime (1 = as recorded)")
    start: int = option(0, min=0, help="index of the first frame")

    def __post_init__(self) -> None:
        check_options(self, SourceError, "replay option ")


class ReplaySource(SourceBase):
    """A recording played back as a Source: the frames as recorded, in order."""

    def __init__(self, config: ReplayConfig | str | Path) -> None:
        self.config = config if isinstance(config, ReplayConfig) else ReplayConfig(path=Path(config))
        self.info = SourceInfo(kind="replay", name=Path(self.config.path).name)
        self.recording: Recording | None = None
        self.playback: Playback | None = None
        self.warnings: list[str] = []  # frames skipped because they could not be read (newest, updated in place)

    def open(self) -> None:
        rec = open_recording(self.config.path)
        if len(rec) == 0:
            raise RecordingError(f"{rec.path / FRAMES} lists no complete frame; there is nothing to replay")
        if self.config.start >= len(rec):
            raise SourceError(f"start={self.config.start} is past the end: {rec.path} has {len(rec)} frames")
        ts = rec.timestamps
        if len(ts) > 1 and np.all(np.diff(ts) >= 0) and ts[-1] > ts[0]:
            offsets = ts - ts[0]
        elif rec.source.fps > 0:
            offsets = np.arange(len(rec)) / rec.source.fps
        else:
            offsets = np.zeros(len(rec))  # no timing recorded: realtime has nothing to follow
        self.playback = Playback(
            len(rec), what=f"the replay of {rec.path}", loop=self.config.loop, realtime=self.config.realtime,
            start=self.config.start, pacer=Pacer(offsets, self.config.speed), loop_hint="use replay:DIR?loop=1 to repeat it",
        )
        self.playback.warnings = self.warnings
        self.recording = rec
        cam = rec.camera
        self.info = SourceInfo(
            kind="replay",
            name=rec.source.name or rec.path.name,
            serial=rec.source.serial,
            width=cam.width if cam else 0,
            height=cam.height if cam else 0,
            fps=rec.source.fps,
            extra={"path": str(rec.path), "frames": len(rec), "recorded_kind": rec.source.kind},
        )
        super().open()

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The next frame in order; a damaged frame is skipped (``warnings``, ``playback.skipped``), the end
        ends or loops as configured (device/formats/recording/playback.py)."""
        if self.recording is None or self.playback is None or not self.is_open:
            raise SourceError("the replay source is not open; call open() or use it in a with block")
        return self.playback.next(self.frame, timeout_s)

    def seek(self, i: int) -> None:
        """Make frame ``i`` the next one ``read`` returns."""
        if self.playback is None:
            raise SourceError("the replay source is not open; call open() or use it in a with block")
        self.playback.seek(i)

    def __len__(self) -> int:
        return len(self.recording) if self.recording is not None else 0

    def frame(self, i: int) -> Frame:
        """Frame ``i`` of the recording, read directly (a damaged frame raises RecordingError)."""
        rec = self.recording
        if rec is None or not self.is_open:
            raise SourceError("the replay source is not open; call open() or use it in a with block")
        frame = rec.frame(i)
        meta = dict(frame.meta)
        meta["replay"] = {"path": str(rec.path), "index": i}
        return dataclasses.replace(frame, meta=meta)

    def close(self) -> None:
        self.recording = None
        self.playback = None
        super().close()


def config_from_spec(spec: SourceSpec) -> ReplayConfig:
    """ReplayConfig from ``replay:DIR?loop=1&realtime=1&speed=2&start=10`` (device.configs)."""
    return configs.from_spec(ReplayConfig, spec, RecordingNotFound("replay needs a recording directory: replay:path/to/recording"))
