"""Shared data types of depthruler: camera intrinsics, frames, options and results.

Every source (devices, recordings, the simulator) produces a :class:`Frame`; the
measurement core consumes it. See ARCHITECTURE.md "Shared types".
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

Method = Literal["robust", "paper", "basic"]
METHODS: tuple[str, ...] = ("robust", "paper", "basic")


class MeasureError(ValueError):
    """Bad input to the measurement core; the message says what to change."""


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of the colour image the disparity is registered to (pixels, zero skew)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
                raise MeasureError(f"camera {name}={value!r} is not a finite number; check the calibration")
        if self.fx <= 0 or self.fy <= 0:
            raise MeasureError(f"camera focal lengths must be positive (fx={self.fx}, fy={self.fy})")
        if int(self.width) != self.width or int(self.height) != self.height or self.width < 1 or self.height < 1:
            raise MeasureError(f"camera size {self.width}x{self.height} must be positive whole pixels")

    def scaled(self, width: int, height: int) -> PinholeCamera:
        """The same camera seen at another resolution (pixel-centre convention)."""
        sx, sy = width / self.width, height / self.height
        return PinholeCamera(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=width,
            height=height,
        )


@dataclass(frozen=True)
class Frame:
    """One colour image with registered disparity.

    ``Z = fx * baseline_m / (disparity + doffs)`` in metres. NaN disparity means no data.
    """

    image: np.ndarray
    disparity: np.ndarray
    camera: PinholeCamera
    baseline_m: float
    doffs: float = 0.0
    confidence: np.ndarray | None = None
    timestamp: float = 0.0
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        validate_frame(self)

    @property
    def shape(self) -> tuple[int, int]:
        return self.disparity.shape  # type: ignore[return-value]

    def depth(self) -> np.ndarray:
        """Depth in metres, NaN where the disparity is missing or non-positive."""
        d = self.disparity.astype(np.float64) + self.doffs
        with np.errstate(divide="ignore", invalid="ignore"):
            z = self.camera.fx * self.baseline_m / d
        z[~(d > 0)] = np.nan
        return z


def validate_frame(frame: Frame) -> None:
    """Raise :class:`MeasureError` naming what is wrong with a frame's arrays or numbers."""
    cam = frame.camera
    if not isinstance(cam, PinholeCamera):
        raise MeasureError(f"frame.camera must be a PinholeCamera, got {type(cam).__name__}")
    disp = frame.disparity
    if not isinstance(disp, np.ndarray) or disp.ndim != 2:
        raise MeasureError(
            f"frame.disparity must be a 2-D array (H x W), got {getattr(disp, 'shape', type(disp).__name__)}"
        )
    if disp.dtype != np.float32:
        raise MeasureError(f"frame.disparity must be float32 pixels, got {disp.dtype}; use .astype(np.float32)")
    h, w = disp.shape
    if (w, h) != (cam.width, cam.height):
        raise MeasureError(
            f"disparity is {w}x{h} but the camera is {cam.width}x{cam.height}; "
            "scale the intrinsics with PinholeCamera.scaled() or resize the disparity"
        )
    img = frame.image
    if not isinstance(img, np.ndarray) or img.shape != (h, w, 3) or img.dtype != np.uint8:
        raise MeasureError(
            f"frame.image must be a {h}x{w}x3 uint8 BGR array matching the disparity, "
            f"got {getattr(img, 'shape', None)} {getattr(img, 'dtype', type(img).__name__)}"
        )
    if frame.confidence is not None:
        conf = frame.confidence
        if not isinstance(conf, np.ndarray) or conf.shape != (h, w) or conf.dtype != np.float32:
            raise MeasureError(
                f"frame.confidence must be a {h}x{w} float32 array in [0, 1] or None, "
                f"got {getattr(conf, 'shape', None)} {getattr(conf, 'dtype', type(conf).__name__)}"
            )
    for name in ("baseline_m", "doffs"):
        value = getattr(frame, name)
        if not isinstance(value, (int, float, np.floating, np.integer)) or not math.isfinite(value):
            raise MeasureError(f"frame.{name}={value!r} is not a finite number; check the calibration")
    if frame.baseline_m <= 0:
        raise MeasureError(f"frame.baseline_m={frame.baseline_m} must be positive (metres)")


@dataclass(frozen=True)
class MeasureOptions:
    """How to measure. See METHOD.md for the meaning of each parameter."""

    method: Method = "robust"
    support_fraction: float = 0.5
    window: int = 5
    extension_px: int = 25
    gap_detection: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise MeasureError(f"method {self.method!r} is unknown; use one of {', '.join(METHODS)}")
        if not (0.5 <= self.support_fraction <= 1.0):
            raise MeasureError(f"support_fraction={self.support_fraction} must lie in [0.5, 1.0]")
        if self.window < 1 or self.window % 2 == 0:
            raise MeasureError(f"window={self.window} must be a positive odd number of pixels")
        if self.extension_px < 3:
            raise MeasureError(f"extension_px={self.extension_px} must be at least 3 pixels")


@dataclass(frozen=True)
class Measurement:
    """The result of one point-to-point measurement (metres, pixels)."""

    distance_m: float
    method: str
    fit: str
    p1_m: tuple[float, float, float]
    p2_m: tuple[float, float, float]
    basic_distance_m: float
    uncertainty_m: float
    n_samples: int
    n_valid: int
    n_support: int
    samples_px: np.ndarray
    support: np.ndarray
    gap_detected: bool
    warnings: tuple[str, ...]
    elapsed_ms: float
    # 95 % interval of the distance (m), and the verdict on the answer (measure.verdict):
    # "good" (the truth is expected inside the interval), "check" or "unreliable", with reasons.
    interval_m: tuple[float, float] = (math.nan, math.nan)
    quality: str = "check"
    reasons: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the same field names (NaN becomes None)."""

        def num(x: float) -> float | None:
            return None if not math.isfinite(x) else float(x)

        return {
            "distance_m": num(self.distance_m),
            "method": self.method,
            "fit": self.fit,
            "p1_m": [num(v) for v in self.p1_m],
            "p2_m": [num(v) for v in self.p2_m],
            "basic_distance_m": num(self.basic_distance_m),
            "uncertainty_m": num(self.uncertainty_m),
            "n_samples": int(self.n_samples),
            "n_valid": int(self.n_valid),
            "n_support": int(self.n_support),
            "samples_px": np.asarray(self.samples_px, dtype=float).tolist(),
            "support": np.asarray(self.support, dtype=bool).tolist(),
            "gap_detected": bool(self.gap_detected),
            "warnings": list(self.warnings),
            "elapsed_ms": float(self.elapsed_ms),
            "interval_m": [num(v) for v in self.interval_m],
            "quality": self.quality,
            "reasons": list(self.reasons),
        }
