"""The ``bag:`` source: a bag's colour/depth pairs as frames in order (``loop``, ``realtime``, ``speed``,
``start``), and its spec parser."""

from __future__ import annotations

from pathlib import Path

from measure import Frame

from device import configs
from device.base import SourceBase, SourceInfo, SourceSpec
from device.errors import SourceError
from device.formats.recording.playback import Playback
from device.pacing import Pacer
from device.sources.bag.config import BagConfig, BagOptions
from device.sources.bag.errors import BagError, BagNotFound
from device.sources.bag.reader import BagReader


class BagSource(SourceBase):
    """The colour/depth pairs of a bag as frames, in order; random access with ``frame(i)`` and ``seek(i)``."""

    def __init__(self, config: BagConfig | str | Path, options: BagOptions = BagOptions()) -> None:
        self.config = config if isinstance(config, BagConfig) else BagConfig(Path(config), options)
        self.path = Path(self.config.path)
        self.options = self.config.options
        self.info = SourceInfo(kind="bag", name=self.path.name)
        self.bag: BagReader | None = None
        self.playback: Playback | None = None
        self.warnings: list[str] = []  # frames skipped because they could not be decoded (newest, updated in place)

    def open(self) -> None:
        bag = BagReader(self.path, self.options)
        c = bag.contents
        if len(c) == 0:
            bag.close()
            raise BagError(
                f"{self.path}: no colour message of {c.layout.color_topic} ({c.color_ns.size}) has a depth message of "
                f"{c.layout.depth_topic} ({c.depth_ns.size}) within {c.max_skew_ns / 1e6:.1f} ms; allow more with skew_ms=N"
            )
        if self.options.start >= len(c):
            bag.close()
            raise SourceError(f"start={self.options.start} is past the end: {self.path} has {len(c)} frames")
        t = c.color_ns[c.pairs[0]]
        offsets = (t - t[0]) / 1e9
        self.playback = Playback(
            len(c), what=f"the bag {self.path}", loop=self.options.loop, realtime=self.options.realtime,
            start=self.options.start, pacer=Pacer(offsets, self.options.speed), loop_hint="use bag:PATH?loop=1 to repeat it",
        )
        self.playback.warnings = self.warnings
        fps = (len(t) - 1) / offsets[-1] if len(t) > 1 and offsets[-1] > 0 else 0.0
        self.bag = bag
        self.info = SourceInfo(
            kind="bag",
            name=self.path.name,
            width=c.color_camera.width,
            height=c.color_camera.height,
            fps=fps,
            extra={"path": str(self.path), "frames": len(c), "layout": c.layout.name, "storage": c.storage,
                   "baseline_m": c.baseline_m, "depth_unit_m": c.depth_unit_m,
                   # Frames are undistorted by these (colour and depth camera_info).
                   "color_distortion": c.color_distortion.model if not c.color_distortion.is_none else "none",
                   "depth_distortion": c.depth_distortion.model if not c.depth_distortion.is_none else "none"},
        )
        super().open()

    def __len__(self) -> int:
        return len(self.bag.contents) if self.bag is not None else 0

    def frame(self, i: int) -> Frame:
        if self.bag is None or not self.is_open:
            raise SourceError("the bag source is not open; call open() or use it in a with block")
        return self.bag.frame(i)

    def seek(self, i: int) -> None:
        """Make frame ``i`` the next one ``read`` returns."""
        if self.playback is None:
            raise IndexError(f"frame {i} is out of range: {self.path} has {len(self)} frames")
        self.playback.seek(i)

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The next frame in order; a damaged message's frame is skipped (``warnings``, ``playback.skipped``),
        the end ends or loops as configured (device/formats/recording/playback.py)."""
        if self.bag is None or self.playback is None or not self.is_open:
            raise SourceError("the bag source is not open; call open() or use it in a with block")
        return self.playback.next(self.bag.frame, timeout_s)

    def close(self) -> None:
        if self.bag is not None:
            self.bag.close()
        self.bag = None
        self.playback = None
        super().close()


def config_from_spec(spec: SourceSpec) -> BagConfig:
    """BagConfig from ``bag:PATH?depth=TOPIC&color=TOPIC&baseline=0.05&depth_unit=0.001&skew_ms=20&loop=1`` (device.configs)."""
    return configs.from_spec(BagConfig, spec, BagNotFound(
        "bag needs a path: bag:path/to/file.bag, bag:path/to/ros2_bag_folder or bag:path/to/file.mcap"))
