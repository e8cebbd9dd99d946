"""The published algorithm (``method="paper"``), docs/method.md steps 1-6 as written.

Steps: sample the segment (step 1, ``measure.request.fit_samples``); FAST-MCD with h =
support_fraction * N on the 3D points (step 2, ``measure.linefit.fit_line``); the exact-fit
branches (step 3: a = b = 0 -> Z of P1, P2 set to -d/c and Eq. 2; another plane -> perpendicular
projection, Eq. 4-5); otherwise the window end points P1, P2 projected onto the first principal
component (step 4, Eq. 6-7); gap detection with Tukey-bisquare ranges of the extensions (step 6:
on a gap, the basic answer). The degenerate plane through the camera centre (all samples on one
image line) is not the surface: the line is fit inside it (``measure.linefit``). Units: pixels in,
metres out; the one-sigma adds the line fit, the window ends' depth errors along the line and
quantization (``measure.uncertainty``).
"""

from __future__ import annotations

import math

import numpy as np

from measure.answer import measurement, window_measurement
from measure.gap import extension_depth, is_gap
from measure.geometry import project_on_line, project_on_plane
from measure.linefit import LineModel, fit_line
from measure.request import NO_DEPTH, Request, fit_samples, focal_baseline, require_resolved_windows
from measure.sampling import SegmentSamples, backproject_depth
from measure.types import Frame, MeasureError, Measurement
from measure.uncertainty import disparity_quantum, distinct_levels, line_fit_sigma, quantization_sigma
from measure.verdict import FEW_SAMPLES, FEW_SHARE, disagreement


def measure_paper(request: Request) -> Measurement:
    """The paper's answer (m) for ``request``; MeasureError when a click window has no depth or the
    segment too few valid samples."""
    require_resolved_windows(request)
    samples = fit_samples(request)
    if not request.basic.ok:
        raise MeasureError(f"{NO_DEPTH}: the paper's method needs depth at both clicks; use method='robust'")
    model = fit_line(samples.points, request.options.support_fraction, request.options.seed)
    return _paper(request, samples, model)


def _quant_term(frame: Frame, samples: SegmentSamples, model: LineModel, p1: np.ndarray, p2: np.ndarray) -> float:
    dist = float(np.linalg.norm(p2 - p1))
    levels = distinct_levels(samples.disparity[model.support])
    mean_z = 0.5 * float(p1[2] + p2[2])
    return quantization_sigma(dist, mean_z, focal_baseline(frame), disparity_quantum(samples.disparity), levels)


def _paper(request: Request, samples: SegmentSamples, model: LineModel) -> Measurement:
    frame, xy1, xy2, options, basic, t0 = request.frame, request.xy1, request.xy2, request.options, request.basic, request.t0
    P1, P2 = basic.p1_m, basic.p2_m
    if model.kind == "constant-depth":
        ends = backproject_depth(frame, np.array([xy1[0], xy2[0]]), np.array([xy1[1], xy2[1]]), np.full(2, model.depth))
        q1, q2 = ends[0], ends[1]
        sigma = _quant_term(frame, samples, model, q1, q2)
    elif model.kind == "plane":
        q1, q2 = project_on_plane(P1, model.plane), project_on_plane(P2, model.plane)
        sigma = _quant_term(frame, samples, model, q1, q2)
    else:
        T, v = model.point, model.direction
        q1, q2 = project_on_line(P1, T, v), project_on_line(P2, T, v)
        fit = line_fit_sigma(
            lambda t, vv: (project_on_line(P1, t, vv), project_on_line(P2, t, vv)),
            T, v, model.scatter, samples.points[model.support],
        )
        # The window end points' own depth errors move them along their rays; the part
        # along v survives the projection.
        along = [abs(float((P / P[2]) @ v)) * s for P, s in zip((P1, P2), basic.z_sigma)]
        sigma = math.sqrt(fit**2 + along[0] ** 2 + along[1] ** 2 + _quant_term(frame, samples, model, q1, q2) ** 2)
    warnings: list[str] = []
    reasons: list[str] = []
    if len(samples.points) < FEW_SAMPLES or len(samples.points) < FEW_SHARE * samples.n_samples:
        reasons.append("few valid samples")
    if options.gap_detection:
        ext = (extension_depth(frame, xy1, xy2, options.extension_px), extension_depth(frame, xy2, xy1, options.extension_px))
        if is_gap(ext, (float(q1[2]), float(q2[2]))):
            return window_measurement(basic, "paper", t0, samples, ("gap detected: both extensions are in front of the end points; basic answer",), gap=True, support=model.support, reasons=reasons)
    # The projected end points leave the clicked pixels: the distance between them is a second opinion.
    other = disagreement(float(np.linalg.norm(q2 - q1)), basic.distance_m)
    if other:
        reasons.append(other)
    return measurement(q1, q2, "paper", model.kind, basic, sigma, samples, model.support, False, warnings, t0, reasons)
