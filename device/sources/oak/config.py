"""The OAK source's configuration (device, sizes in pixels, fps, stereo settings) and its spec parser."""

from __future__ import annotations

from dataclasses import dataclass, fields

import depthai as dai

from device.base import SourceSpec, parse_flag
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
    pixels (v2 had the opposite scale: a v2 value of 200-245 would drop most depth in v3).
    ``align``: "color" (depth on the colour image), "left" (the rectified left mono image, with the
    confidence map) or "auto" (colour when the device has a colour camera). ``auto_calibration``:
    DepthAI's automatic recalibration, "off" (default), "on_start" or "continuous" (may write a
    new calibration to the device). ``search_timeout_ms`` bounds how long
    :meth:`OakSource.open` looks for the device.
    """

    mxid: str = ""
    fps: float = 15.0
    width: int = 1280
    height: int = 720
    mono_width: int = 640
    mono_height: int = 400
    preset: str = "DEFAULT"
    subpixel: bool | None = None
    lr_check: bool | None = None
    extended_disparity: bool | None = None
    confidence_threshold: int | None = None
    confidence_map: bool = True
    align: str = "auto"
    auto_calibration: str = "off"
    search_timeout_ms: int = 1000

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise SourceError(f"OAK preset {self.preset!r} is unknown; use one of {', '.join(PRESETS)}")
        if not (0 < self.fps <= 120):
            raise SourceError(f"OAK fps={self.fps} must lie in (0, 120]")
        for name in ("width", "height", "mono_width", "mono_height"):
            if getattr(self, name) < 16:
                raise SourceError(f"OAK {name}={getattr(self, name)} must be at least 16 pixels")
        if self.confidence_threshold is not None and not (0 <= self.confidence_threshold <= 255):
            raise SourceError(f"OAK confidence_threshold={self.confidence_threshold} must lie in 0..255")
        if self.align not in ALIGNS:
            raise SourceError(f"OAK align={self.align!r} is unknown; use one of {', '.join(ALIGNS)}")
        if self.auto_calibration not in AUTO_CALIBRATION:
            raise SourceError(f"OAK auto_calibration={self.auto_calibration!r} is unknown; "
                              f"use one of {', '.join(AUTO_CALIBRATION)}")
        if not (100 <= self.search_timeout_ms <= 60_000):
            raise SourceError(f"OAK search_timeout_ms={self.search_timeout_ms} must lie in 100..60000")

    @property
    def size(self) -> tuple[int, int]:
        return (self.width, self.height)


def config_from_spec(spec: SourceSpec) -> OakConfig:
    """OakConfig from ``oak[:<mxid>][?preset=HIGH_DETAIL&fps=10&size=1280x720&subpixel=1&lr_check=1
    &extended_disparity=0&confidence_threshold=55&confidence_map=1&align=auto&auto_calibration=off
    &search_timeout_ms=2000]``; options left out keep the preset's (or the default) value."""
    known = {f.name for f in fields(OakConfig)} - {"mxid", "width", "height"}
    kwargs: dict = {"mxid": spec.target}
    for key, value in spec.params.items():
        try:
            if key == "size":
                w, _, h = value.lower().partition("x")
                kwargs["width"], kwargs["height"] = int(w), int(h)
            elif key == "preset":
                kwargs["preset"] = value.upper()
            elif key in ("align", "auto_calibration"):
                kwargs[key] = value.lower()
            elif key in ("subpixel", "lr_check", "extended_disparity", "confidence_map"):
                kwargs[key] = parse_flag(value)
            elif key == "fps":
                kwargs["fps"] = float(value)
            elif key in ("confidence_threshold", "search_timeout_ms", "mono_width", "mono_height"):
                kwargs[key] = int(value)
            else:
                raise SourceError(
                    f"unknown OAK option {key!r} in {str(spec)!r}; use: size, {', '.join(sorted(known))}"
                )
        except (ValueError, KeyError) as exc:
            raise SourceError(f"OAK option {key}={value!r} in {str(spec)!r} is not valid") from exc
    return OakConfig(**kwargs)
