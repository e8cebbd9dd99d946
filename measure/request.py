"""One measurement request (frame, two clicks, options), checked, and the checks every method shares.

A method implementation (``measure.distance.METHOD_IMPLEMENTATIONS``) receives a :class:`Request`:
the validated clicks (px), the options, the basic window ends (``measure.basic.basic_ends``) and the
start time. Each check raises :class:`MeasureError` with a message that says what to change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from measure.sampling import SegmentSamples, check_point, sample_segment
from measure.types import Frame, MeasureError, MeasureOptions, validate_frame

if TYPE_CHECKING:
    from measure.basic import BasicEnds

MIN_FIT_SAMPLES = 5  # fewer valid samples than this cannot support a robust 3-D fit
NO_DEPTH = "endpoint has no depth within window"
BEYOND_RANGE = (
    "depth beyond the measurable range: an end point's disparity is not distinguishable from zero "
    "(infinite depth) for this camera; click on nearer surfaces or check the disparity map's scale"
)
RESOLVED_SIGMAS = 2.0  # an end's disparity must lie this many of its standard errors above zero


@dataclass(frozen=True)
class Request:
    """A validated request: ``frame``, clicks ``xy1``, ``xy2`` (x, y floats, px), ``options``, the
    window ends ``basic`` of both clicks and the start time ``t0`` (``time.perf_counter()``, s)."""

    frame: Frame
    xy1: tuple[float, float]
    xy2: tuple[float, float]
    options: MeasureOptions
    basic: BasicEnds
    t0: float


def validate_request(frame: Frame, p1: object, p2: object, options: MeasureOptions) -> tuple[tuple[float, float], tuple[float, float]]:
    """Check the frame, options and clicks; return the clicks as floats. Raises MeasureError."""
    if not isinstance(frame, Frame):
        raise MeasureError(f"frame must be a measure.Frame, got {type(frame).__name__}")
    if not isinstance(options, MeasureOptions):
        raise MeasureError(f"options must be a measure.MeasureOptions, got {type(options).__name__}")
    validate_frame(frame)  # validate_camera: every intrinsic finite and in its physical range
    xy1 = check_point(frame, p1, "p1")
    xy2 = check_point(frame, p2, "p2")
    if xy1 == xy2:
        raise MeasureError("p1 and p2 are the same pixel; click two different points")
    return xy1, xy2


def focal_baseline(frame: Frame) -> float:
    """fx * B (px m): depth Z = fB / (d + doffs)."""
    return frame.camera.fx * frame.baseline_m


def resolved(d: float, se: float) -> bool:
    """A disparity ``d`` (px, doffs included) a depth can be taken from: more than ``RESOLVED_SIGMAS``
    of its standard error ``se`` (px) above zero. Closer to zero, depth = fB/d is unbounded within
    the error (its relative error is above 1/RESOLVED_SIGMAS)."""
    return d > RESOLVED_SIGMAS * se


def require_resolved_windows(request: Request) -> None:
    """Raise BEYOND_RANGE when a click window's depth is unbounded within its error (the methods that
    start from the window ends: basic and paper)."""
    basic = request.basic
    # Relative depth error = relative disparity error: at or above 1/RESOLVED_SIGMAS the depth is unbounded.
    if basic.ok and any(not resolved(1.0, s / float(p[2])) for s, p in zip(basic.z_sigma, (basic.p1_m, basic.p2_m))):
        raise MeasureError(BEYOND_RANGE)


def fit_samples(request: Request) -> SegmentSamples:
    """The segment's samples (docs/method.md step 1) when there are enough for a robust fit: at least
    ``MIN_FIT_SAMPLES`` pixels and as many valid ones; otherwise MeasureError."""
    samples = sample_segment(request.frame, request.xy1, request.xy2)
    if samples.n_samples < MIN_FIT_SAMPLES:
        raise MeasureError(
            f"p1 and p2 are only {samples.n_samples - 1} px apart: too short for a robust fit; "
            "click farther apart or use method='basic'"
        )
    if len(samples.points) < MIN_FIT_SAMPLES:
        # Depth at the end windows alone, with none along the line, is not worth a number.
        raise MeasureError(
            f"no valid disparity along the segment from p1 to p2 (only {len(samples.points)} valid samples, "
            f"{MIN_FIT_SAMPLES} needed); measure where the depth map has data, or use method='basic'"
        )
    return samples
