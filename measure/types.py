"""Shared data types of depthruler: camera intrinsics, frames, options and results.

Every source (devices, recordings, the simulator) produces a :class:`Frame`; the
measurement core consumes it. See docs/design.md "Shared types".
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from measure.errors import MeasureError
from measure.options import MAX_CLICK_PX, METHODS, Method, MeasureOptions

# Physical ranges of the numbers a calibration gives (outside them the numbers are a unit or
# parsing mistake, and the arithmetic overflows long before it measures anything).
# Focal length per pixel of the image's larger side: 0.05 is a 169-degree field of view, 1e4
# a 0.006-degree one (or a 0.6-degree one of an image cropped to 1/100 of its side).
FOCAL_PER_SIZE = (0.05, 1e4)
# Principal point: within this many image sizes of the image (a crop's lies outside it).
PRINCIPAL_POINT_SIZES = 1e3
# Stereo baseline in metres: 0.1 mm (dual-pixel sensors) to 1 km.
BASELINE_RANGE_M = (1e-4, 1e3)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, (bool, np.bool_))


def validate_camera(cam: PinholeCamera) -> None:
    """Raise :class:`MeasureError` naming the intrinsic that is not a number, not finite or
    outside its physical range (``FOCAL_PER_SIZE``, ``PRINCIPAL_POINT_SIZES``)."""
    for name in ("width", "height"):
        value = getattr(cam, name)
        if not _is_number(value) or not math.isfinite(value) or int(value) != value or value < 1:
            raise MeasureError(f"camera {name}={value!r} must be a positive whole number of pixels")
    for name in ("fx", "fy", "cx", "cy"):
        value = getattr(cam, name)
        if not _is_number(value) or not math.isfinite(value):
            raise MeasureError(f"camera {name}={value!r} is not a finite number; check the calibration")
    size = max(int(cam.width), int(cam.height))
    lo, hi = FOCAL_PER_SIZE
    for name in ("fx", "fy"):
        value = getattr(cam, name)
        if value <= 0:
            raise MeasureError(f"camera focal lengths must be positive ({name}={value})")
        if not lo * size <= value <= hi * size:
            raise MeasureError(
                f"camera {name}={value:g} px is outside the physical range [{lo * size:g}, {hi * size:g}] "
                f"for a {cam.width}x{cam.height} image (a field of view of 169 to 0.006 degrees); "
                "check the calibration's units and that it belongs to this resolution"
            )
    reach = PRINCIPAL_POINT_SIZES * size
    for name, extent in (("cx", cam.width), ("cy", cam.height)):
        value = getattr(cam, name)
        if not -reach <= value <= extent + reach:
            raise MeasureError(
                f"camera {name}={value:g} px is more than {PRINCIPAL_POINT_SIZES:g} image sizes outside the "
                f"{cam.width}x{cam.height} image; check the calibration"
            )


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of the colour image the disparity is registered to (pixels, zero skew).

    A pixel (x, y) at depth Z (m) is the point ``((x - cx) Z / fx, (y - cy) Z / fy, Z)``
    (docs/method.md, Eq. 2). Pixel centres are at whole coordinates.

    Args:
        fx: horizontal focal length (float, px); within ``FOCAL_PER_SIZE`` times the larger image side.
        fy: vertical focal length (float, px); same range as ``fx``.
        cx: principal point column (float, px).
        cy: principal point row (float, px).
        width: image width W (int, px, >= 1).
        height: image height H (int, px, >= 1).

    Returns:
        A frozen, validated camera; raises :class:`MeasureError` naming a value that is not a
        finite number or outside its physical range.

    Examples:
        >>> from measure import PinholeCamera
        >>> cam = PinholeCamera(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
        >>> half = cam.scaled(32, 24)
        >>> print(half.fx, half.cx, half.width)
        30.0 15.5 32
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        validate_camera(self)

    def scaled(self, width: int, height: int) -> PinholeCamera:
        """The same camera seen at another resolution (pixel-centre convention).

        Args:
            width: new image width (int, px).
            height: new image height (int, px).

        Returns:
            A :class:`PinholeCamera` with focal lengths and principal point scaled to ``width x height``.
        """
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

    Args:
        image: colour image, (H, W, 3) uint8, BGR.
        disparity: disparity registered to ``image``, (H, W) float32, px; NaN where there is no data.
        camera: intrinsics of ``image``; ``camera.width x camera.height`` must be ``W x H``.
        baseline_m: stereo baseline (float, m, in ``BASELINE_RANGE_M``).
        doffs: disparity offset added before the division (float, px): the difference of the two
            cameras' principal points (Middlebury's ``doffs``); 0 for rectified pairs.
        confidence: optional per-pixel confidence, (H, W) float32 in [0, 1], or None.
        timestamp: capture time (float, s).
        meta: free-form source information (mapping of str to JSON-ready values).

    Returns:
        A frozen, validated frame; raises :class:`MeasureError` naming a wrong shape, dtype or number.

    Examples:
        >>> import numpy as np
        >>> from measure import Frame, PinholeCamera
        >>> cam = PinholeCamera(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
        >>> disparity = np.full((48, 64), 12.0, dtype=np.float32)  # a plane 0.5 m away
        >>> frame = Frame(np.zeros((48, 64, 3), np.uint8), disparity, cam, baseline_m=0.1)
        >>> frame.shape
        (48, 64)
        >>> print(frame.depth()[0, 0])  # 60 px * 0.1 m / 12 px
        0.5
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
        """(H, W) of the disparity, px."""
        return self.disparity.shape  # type: ignore[return-value]

    def valid(self, disparity: np.ndarray) -> np.ndarray:
        """Where ``disparity`` (px) is one a camera can produce: finite, ``d + doffs > 0`` (in
        front of the camera) and at most the image width (the match lies inside the other image).

        Args:
            disparity: disparities of any shape (px).

        Returns:
            Boolean array of the same shape.
        """
        d = np.asarray(disparity)
        # d > -doffs is d + doffs > 0 (a rounded sum has the sign of the exact one) without the sum's
        # overflow, so without an errstate context, which costs more than the test on a segment. The two
        # comparisons are the finiteness test too: NaN fails both, -inf the first and +inf the second.
        return (d > -self.doffs) & (d <= self.camera.width)

    def depth(self) -> np.ndarray:
        """Depth in metres, NaN where the disparity is invalid (:meth:`valid`).

        Returns:
            (H, W) float64 array of Z (m).
        """
        ok = self.valid(self.disparity)
        z = np.full(self.disparity.shape, np.nan)
        z[ok] = self.camera.fx * self.baseline_m / (self.disparity[ok].astype(np.float64) + self.doffs)
        return z


def validate_frame(frame: Frame) -> None:
    """Raise :class:`MeasureError` naming what is wrong with a frame's arrays or numbers."""
    cam = frame.camera
    if not isinstance(cam, PinholeCamera):
        raise MeasureError(f"frame.camera must be a PinholeCamera, got {type(cam).__name__}")
    validate_camera(cam)
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
        if not _is_number(value) or not math.isfinite(value):
            raise MeasureError(f"frame.{name}={value!r} is not a finite number; check the calibration")
    if frame.baseline_m <= 0:
        raise MeasureError(f"frame.baseline_m={frame.baseline_m} must be positive (metres)")
    # doffs is the difference of the two cameras' principal points: the same range applies.
    reach = (2 * PRINCIPAL_POINT_SIZES + 1) * max(w, h)
    if abs(frame.doffs) > reach:
        raise MeasureError(
            f"frame.doffs={frame.doffs:g} px is larger than a difference of two principal points can be "
            f"({reach:g} px for a {w}x{h} image); check the calibration"
        )
    lo, hi = BASELINE_RANGE_M
    if not lo <= frame.baseline_m <= hi:
        raise MeasureError(
            f"frame.baseline_m={frame.baseline_m:g} is outside the physical range [{lo:g}, {hi:g}] m; "
            "check the calibration's units (metres, not millimetres)"
        )


@dataclass(frozen=True)
class Measurement:
    """The result of one point-to-point measurement (metres, pixels).

    Made by :func:`measure.measure_distance` and :func:`measure.sequence.measure_sequence`.

    Args:
        distance_m: the distance |P2 - P1| (float, m).
        method: the method that answered: ``"robust"``, ``"paper"`` or ``"basic"`` (str).
        fit: which model gave the end points: ``"line"``, ``"constant-depth"``, ``"surfaces"`` or ``"none"``
            (window medians) (str).
        p1_m: 3D point of the first click (x, y, z) in the camera frame (m).
        p2_m: 3D point of the second click (m).
        basic_distance_m: the basic method's distance, for comparison (float, m; NaN without depth at a click).
        uncertainty_m: one-sigma uncertainty of ``distance_m`` (float, m).
        n_samples: pixels sampled along the segment (int).
        n_valid: of them, with valid disparity (int).
        n_support: of them, in the robust fit's support (int).
        samples_px: (n_valid, 2) float array of the valid samples' (x, y) (px).
        support: (n_valid,) bool array, True for samples in the fit's support.
        gap_detected: an end was clicked on a depth gap and moved to the surface (bool).
        warnings: human-readable warnings (tuple of str).
        elapsed_ms: time the measurement took (float, ms).
        interval_m: 95 % interval of the distance (low, high) (m).
        quality: verdict on the answer (measure.verdict): ``"good"`` (the truth is expected inside the
            interval), ``"check"`` or ``"unreliable"`` (str).
        reasons: why the verdict is not ``"good"`` (tuple of str).
        frames_used: frames of a still scene pooled into the answer (int, 1 for one frame).
        single_frame_uncertainty_m: one-sigma the newest frame alone would have had (float, m); the
            pooling gain is its ratio to ``uncertainty_m``.

    Returns:
        A frozen result; :meth:`to_dict` gives its JSON form.

    Examples:
        >>> import numpy as np
        >>> from measure import Frame, PinholeCamera
        >>> cam = PinholeCamera(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
        >>> disparity = np.full((48, 64), 12.0, dtype=np.float32)  # a plane 0.5 m away
        >>> frame = Frame(np.zeros((48, 64, 3), np.uint8), disparity, cam, baseline_m=0.1)
        >>> from measure import measure_distance
        >>> m = measure_distance(frame, (10, 24), (54, 24))
        >>> print(m.method, m.quality, round(m.distance_m, 4), m.frames_used)
        robust good 0.3667 1
        >>> sorted(m.to_dict())[:3]
        ['basic_distance_m', 'distance_m', 'elapsed_ms']
    """

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
    interval_m: tuple[float, float] = (math.nan, math.nan)
    quality: str = "check"
    reasons: tuple[str, ...] = ()
    frames_used: int = 1
    single_frame_uncertainty_m: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the same field names (NaN becomes None).

        Returns:
            dict of str to floats, ints, bools, strs, None and lists of them.
        """

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
            "frames_used": int(self.frames_used),
            "single_frame_uncertainty_m": num(self.single_frame_uncertainty_m),
        }
