"""Gap detection (docs/method.md step 6): is the segment behind both of its end points?

- The paper's rule (``is_gap``, used by the paper method and the z-only ablation): the range of each
  extension beyond an end point (away from the other) is the Tukey bisquare M-estimate of its valid
  pixels' depths (``extension_depth``); a gap when both are in front of the refined end points,
  ``Z_ext1 < Z1'`` and ``Z_ext2 < Z2'``.
- The robust method's rule (``clear_gap_ends``), in disparity: each end's surface is
  its extension's valid pixels together with the segment's samples next to the click that lie in
  front of the segment's robust line and are not supported by it (``leading_run``), up to the first the
  extension's own bisquare would not weigh (``_end_run``). It needs
  ``MIN_EXTENSION_SAMPLES`` samples, and its Tukey location must exceed the segment's line at the end
  by ``GAP_STEP_REL`` and by ``GAP_SIGMAS`` standard errors of the difference, each inflated for the
  lag-one correlation of its residuals. On a gap the answer is measured between the clicks' rays at
  the two end surfaces' depths; each surface also carries the rounding error its samples share
  (``measure.uncertainty.rounding_sigma`` on the levels near its location).

Why evidence at both ends: on a poster on a wall the bare comparison is a coin toss per side, and
smooth SGBM noise makes per-pixel standard errors too small (docs/decisions/gap-evidence.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.robust_range import TUKEY_C, median, tukey_location, tukey_scale
from measure.sampling import depth_of, extension_pixels, valid_disparity
from measure.types import Frame
from measure.uncertainty import correlation_inflation, rounding_sigma


@dataclass(frozen=True)
class ExtensionDepth:
    depth_m: float  # Tukey location; NaN without valid pixels
    se_m: float  # its standard error
    n_valid: int


def extension_depth(frame: Frame, start: tuple[float, float], other: tuple[float, float], length: int) -> ExtensionDepth:
    """Robust depth (m) of the ``length``-pixel extension beyond ``start`` away from ``other``."""
    px = extension_pixels(frame, start, other, length)
    d = frame.disparity[px[:, 1], px[:, 0]]
    d = d[valid_disparity(frame, d)]
    if d.size == 0:
        return ExtensionDepth(math.nan, math.nan, 0)
    z, se = tukey_location(depth_of(frame, d))
    return ExtensionDepth(z, se, int(d.size))


def is_gap(ext: tuple[ExtensionDepth, ExtensionDepth], z_refined: tuple[float, float], margins: tuple[float, float] = (0.0, 0.0)) -> bool:
    """Both extensions in front of their refined end points by more than ``margins`` (m).

    An extension without depth (off the image, a hole) cannot show a gap.
    """
    return bool(
        all(
            math.isfinite(e.depth_m) and math.isfinite(z) and e.depth_m < z - m
            for e, z, m in zip(ext, z_refined, margins)
        )
    )


MIN_EXTENSION_SAMPLES = 10  # samples each end's surface needs before it may show a gap
GAP_STEP_REL = 0.15  # each end's surface at least this much nearer (relative disparity = depth) than the segment's
GAP_SIGMAS = 2.0  # ... and by this many correlation-inflated standard errors of the two estimates
# A gap answer's one-sigma is its end surfaces' and clicks' model sigma as it is: the segment's SIGMA_SCALE
# corrects the line model's ends on real stereo, which a gap's end surfaces do not use; measured unscaled,
# their 2-sigma covers the truth as often as it says (docs/decisions/gap-sigma.md).
GAP_SIGMA_SCALE = 1.0


@dataclass(frozen=True)
class EndSurface:
    """The surface an end point is on, seen from the segment: its extension's valid pixels and the
    segment's leading samples in front of the segment's own line (px of disparity)."""

    disparity: float  # Tukey location (px); NaN without samples
    se: float  # its correlation-inflated standard error (px)
    n_valid: int
    rounding: float = 0.0  # the disparity rounding error its samples share (px, one sigma)


def _end_run(frame: Frame, start: tuple[float, float], other: tuple[float, float], length: int, leading: np.ndarray, quantum: float = 0.0) -> np.ndarray:
    """The samples of one end's surface (px): its extension's valid pixels and the first of ``leading``
    (nearest the end first) up to the first that the extension's own bisquare would not weigh (farther
    from its median than ``TUKEY_C`` of its scale, that at least the rounding's ``quantum / sqrt(12)``):
    past the edge the segment runs on onto another surface (a box's side face receding from the camera)."""
    px = extension_pixels(frame, start, other, length)
    d = frame.disparity[px[:, 1], px[:, 0]]
    d = d[valid_disparity(frame, d)].astype(np.float64)
    lead = np.asarray(leading, dtype=np.float64)
    if d.size and lead.size:
        far = np.abs(lead - median(d)) > TUKEY_C * max(tukey_scale(d), quantum / math.sqrt(12.0))
        if far.any():
            lead = lead[: int(np.argmax(far))]
    # Nearest to the end first on both sides: the run is in image order through the click.
    return np.concatenate([d[::-1], lead])


def _surface_of(run: np.ndarray, quantum: float) -> EndSurface:
    """Tukey location of a non-empty run (px), its correlation-inflated standard error and the rounding
    error shared by the levels of step ``quantum`` (px) that the location rests on (the bisquare's
    inliers), with their scatter about it as the dithering noise."""
    loc, se = tukey_location(run)
    res = run - loc
    inflate = correlation_inflation(res)
    rounding = 0.0
    if quantum > 0:
        near = np.abs(res) < TUKEY_C * tukey_scale(run)
        near = near if near.any() else np.ones(run.size, bool)  # all values equal: one level
        rounding = rounding_sigma(quantum, int(np.unique(run[near]).size), float(np.sqrt(np.mean(res[near] ** 2))))
    return EndSurface(loc, se * inflate, int(run.size), rounding)


def leading_run(residuals: np.ndarray, support: np.ndarray) -> int:
    """Number of samples from the start of ``residuals`` (px, sample minus line, nearest the end first)
    that the line does not support and that lie in front of it (positive residual)."""
    ahead = (residuals > 0) & ~support
    return int(np.argmin(ahead)) if not ahead.all() else int(ahead.size)


def _clear_at(e: EndSurface, d: float, s: float, doffs: float) -> bool:
    """The gap rule at one end: surface ``e`` against the segment's disparity ``d`` (px, standard error ``s``)."""
    if e.n_valid < MIN_EXTENSION_SAMPLES or not (math.isfinite(e.disparity) and math.isfinite(d) and d + doffs > 0):
        return False
    step = e.disparity - d
    return step > GAP_STEP_REL * (d + doffs) and step > GAP_SIGMAS * math.hypot(e.se, s)


def clear_gap_ends(frame: Frame, xy1: tuple[float, float], xy2: tuple[float, float], length: int, leading: tuple[np.ndarray, np.ndarray],
                   d_segment: tuple[float, float], se_segment: tuple[float, float], quantum: float = 0.0) -> tuple[EndSurface, EndSurface] | None:
    """Both ends' surfaces when they show a clear gap, else None (the module docstring's rule): at each
    end, the ``length``-px extension's valid pixels beyond the click together with its ``leading``
    samples (the segment's next to the click in front of its line, nearest first), a surface of at
    least ``MIN_EXTENSION_SAMPLES`` samples whose Tukey location exceeds the segment's disparity there
    (``d_segment``, px, standard errors ``se_segment``) by ``GAP_STEP_REL`` of it and by ``GAP_SIGMAS``
    combined standard errors. End by end: the second end is not read once the first shows no gap, and
    no Tukey location is computed where it cannot pass (a weighted mean lies within its samples' range,
    so an end whose largest sample does not exceed the segment's disparity by ``GAP_STEP_REL`` has none).
    ``quantum`` is the disparity step (px) for each surface's rounding error (0: none)."""
    ends = []
    for (a, b), lead, d, s in zip(((xy1, xy2), (xy2, xy1)), leading, d_segment, se_segment):
        run = _end_run(frame, a, b, length, lead, quantum)
        if run.size < MIN_EXTENSION_SAMPLES or not (math.isfinite(d) and d + frame.doffs > 0):
            return None
        top = float(run.max())
        # 1e-9: the bound holds for the float mean too (its rounding is far below it).
        if top + 1e-9 * (abs(top) + 1.0) - d <= GAP_STEP_REL * (d + frame.doffs):
            return None
        e = _surface_of(run, quantum)
        if not _clear_at(e, d, s, frame.doffs):
            return None
        ends.append(e)
    return ends[0], ends[1]
