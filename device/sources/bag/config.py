"""The bag source's configuration: the bag's path and its spec options (units: metres, milliseconds)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from measure import check_options, option

from device.errors import SourceError


TOPIC_KEYS = ("depth", "color", "depth_info", "color_info")


def _topic_keys() -> dict[str, type]:
    return dict.fromkeys(TOPIC_KEYS, str)


@dataclass(frozen=True)
class BagOptions:
    """A bag's spec options; spelling, bounds and help of each in its field metadata."""

    topics: tuple[tuple[str, str], ...] = option(
        (), extras=_topic_keys, example=(("depth", "/camera/depth/image_rect_raw"),),
        help="topics of a bag whose layout is not recognised: depth, color, depth_info, color_info")
    baseline_m: float | None = option(None, key="baseline", min=0.0, min_open=True, unit="m",
                                      default_text="the recorded one, else 0.075", help="baseline the disparity is expressed with")
    depth_unit_m: float | None = option(None, key="depth_unit", min=0.0, min_open=True, unit="m",
                                        default_text="the bag's (ROS: 0.001)", help="metres per 16-bit depth step")
    skew_ms: float | None = option(None, min=0.0, min_open=True, unit="ms", default_text="half the colour period, 5-50",
                                   help="largest time between a colour and its depth message")
    registered: bool = option(False, help="treat the depth as registered to the colour image")
    loop: bool = option(False, help="start again at the end")
    realtime: bool = option(False, help="pace frames by their recorded times")
    speed: float = option(1.0, min=0.0, min_open=True, help="playback speed with realtime (1 = as recorded)")
    start: int = option(0, min=0, help="index of the first frame")

    def __post_init__(self) -> None:
        check_options(self, SourceError, "bag option ")


@dataclass(frozen=True)
class BagConfig:
    """A bag source: the bag (ROS 1 .bag, ROS 2 folder or .mcap) and its options."""

    path: Path = option(target=True, key="path", example="captures/desk.bag",
                        help="a ROS 1 .bag, a ROS 2 bag folder, or a .mcap / .db3 file")
    options: BagOptions = option(BagOptions(), nested=True, help="the bag's options")
