"""The OAK source's configuration (device, sizes in pixels, fps, stereo settings) and its spec parser."""

from __future__ import annotations

from dataclasses import dataclass

import depthai as dai

from measure import check_options, option

from device import configs
from device.base import SourceSpec
from device.errors import SourceError

PRESETS: tuple[str, ...] = (
    "FAST_ACCURACY",
    "FAST_DENSITY",
    "DEFAULT",
    "FACE",
    "HIGH_DETAIL",
    "ROBOTICS",
    "DENSITY",
    "ACCURACY",
)
ALIGNS: tuple[str, ...] = ("auto", "color", "left")
AUTO_CALIBRATION = {
    "off": dai.Pipeline.AutoCalibrationMode.OFF,
    "on_start": dai.Pipeline.AutoCalibrationMode.ON_START,
    "continuous": dai.Pipeline.AutoCalibrationMode.CONTINUOUS,
}
COLOR_SOCKET = dai.CameraBoardSocket.CAM_A


@dataclass(frozen=True)
class OakConfig:
    """How to run an OAK: which device, output size and rate, and the stereo settings.

    ``subpixel``, ``lr_check``, ``extended_disparity`` and ``confidence_threshold`` are None
    ("as the preset says") unless set. ``confidence_threshold`` has DepthAI v3's meaning: 0-255,
    pixels whose confidence (255 = best) is above it are kept, so a *higher* value keeps *fewer*
    pixels (v2 had the opposite scale: a v2 value of 200-245 would drop most depth in v3); the
    DEFAULT preset keeps pixels above 15 on RVC2 and 20 on RVC4. Whatever the preset, the
    temporal filter, decimation, hole filling and spatial filter are off
    (:func:`device.sources.oak.pipeline.measurement_filters`).
    ``align``: "color" (depth on the colour image), "left" (the rectified left mono image, with the
    confidence map) or "auto" (colour when the device has a colour camera). ``auto_calibration``:
    DepthAI's automatic recalibration, "off" (default), "on_start" or "continuous" (may write a
    new calibration to the device). ``search_timeout_ms`` bounds how long
    :meth:`OakSource.open` looks for the device.
    """

    mxid: str = option("", target=True, key="mxid", example="1844301011B546F500",
                       default_text="the first OAK found", help="the device id (`depthruler devices` lists them)")
    fps: float = option(15.0, min=0.0, max=120.0, min_open=True, unit="frames/s", help="camera frame rate")
    width: int = option(1280, joined=("size", 0), min=16, unit="px", help="output (colour) width")
    height: int = option(720, joined=("size", 1), min=16, unit="px", help="output (colour) height")
    mono_width: int = option(640, min=16, unit="px", help="mono (stereo input) width")
    mono_height: int = option(400, min=16, unit="px", help="mono (stereo input) height")
    preset: str = option("DEFAULT", choices=PRESETS, case="upper", help="DepthAI v3 stereo preset")
    subpixel: bool | None = option(None, default_text="the preset's", help="subpixel disparity")
    lr_check: bool | None = option(None, default_text="the preset's", help="left-right consistency check")
    extended_disparity: bool | None = option(None, default_text="the preset's", help="extended disparity range (closer objects)")
    confidence_threshold: int | None = option(None, min=0, max=255, default_text="the preset's",
                                              help="keep pixels whose confidence (255 = best) is above this (v3 scale)")
    confidence_map: bool = option(True, help="deliver the confidence map (with align=left)")
    align: str = option("auto", choices=ALIGNS, case="lower", help="auto | color: depth on the colour image | left: the rectified left mono")
    auto_calibration: str = option("off", choices=tuple(AUTO_CALIBRATION), case="lower",
                                   help="DepthAI's automatic recalibration (on_start/continuous may write to the device)")
    search_timeout_ms: int = option(1000, min=100, max=60_000, unit="ms", help="how long open() looks for the device")

    def __post_init__(self) -> None:
        check_options(self, SourceError, "OAK option ")

    @property
    def size(self) -> tuple[int, int]:
        return (self.width, self.height)


def config_from_spec(spec: SourceSpec) -> OakConfig:
    """OakConfig from ``oak[:<mxid>][?preset=HIGH_DETAIL&fps=10&size=1280x720&...]`` (device.configs);
    options left out keep the preset's (or the default) value."""
    return configs.from_spec(OakConfig, spec)
