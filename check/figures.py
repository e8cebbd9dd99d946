"""The check's numbers from a :class:`check.result.CheckResult`: accuracy, bias, spread, the board as a target.

Lengths in m (mm where the key says so), errors in % of the true length. Steps: per pair the
accuracy (Eq. 8) and signed error; per length bin the mean accuracy and median error; the bias as
the median error of the long pairs (3 squares or more, where end-point noise is small against the
length) with a standard error that counts corners, not pairs (pairs share corners); a robust line
``error = k * length + c`` that tells a scale (k) from a fixed end-point offset (c); the board's
pose, fill rate and plane fits averaged over frames; the frame-to-frame spread, the median over
pairs seen in two frames or more of each pair's standard deviation.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from check.errors import CheckError
from check.pairs import PairResult
from check.result import CheckResult

LONG_SQUARES = 2.5  # "long" pairs: 3 squares or more
LENGTH_BINS = ((1.0, 1.5, "1 square"), (1.5, 2.5, "2 squares"), (2.5, 4.5, "3-4 squares"), (4.5, math.inf, "5+ squares"))


def robust_line(x: np.ndarray, y: np.ndarray, iterations: int = 10) -> tuple[float, float]:
    """Slope and intercept of y = k x + c, bisquare-reweighted (a few wild pairs do not set them)."""
    A = np.stack([x, np.ones_like(x)], axis=1)
    k, c = float(np.median(y / x)), 0.0  # start from a pure scale, which a few wild pairs do not move
    for _ in range(iterations):
        r = y - (k * x + c)
        scale = max(1.4826 * float(np.median(np.abs(r))), 1e-12)
        sw = np.clip(1 - (r / (4.685 * scale)) ** 2, 0, None) + 1e-6  # sqrt of the bisquare weight
        (k, c), *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    return float(k), float(c)


def _mean(values: Iterable[float]) -> float | None:
    v = np.asarray(list(values), np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


def figures(result: CheckResult) -> dict:
    """The check's numbers (JSON-ready; lengths in m, errors in % of the true length)."""
    pr = result.pairs
    if not pr:
        raise CheckError("the board was found but no corner pair could be measured (no valid disparity on it); "
                         "add light or texture, or move closer")
    true = np.array([p.pair.length_m for p in pr])
    meas = np.array([p.measured_m for p in pr])
    acc = np.array([p.accuracy for p in pr])
    err = np.array([p.error_pct for p in pr])
    half = np.array([(p.interval_m[1] - p.interval_m[0]) / 2 for p in pr]) / meas * 100.0
    # Pairs share corners, so their errors are not independent: the standard error counts corners, not pairs.
    n_eff = max(int(np.mean([v.n_corners for v in result.views])), 2)
    sq = np.array([p.pair.squares for p in pr])
    per_length = {}
    for lo, hi, label in LENGTH_BINS:
        sel = (sq >= lo) & (sq < hi)
        if sel.any():
            per_length[label] = {"n": int(sel.sum()), "mean_accuracy": float(acc[sel].mean()),
                                 "bias_pct": float(np.median(err[sel])), "spread_pct": _mad(err[sel]),
                                 "interval_pm_pct": float(np.median(half[sel]))}
    # error_m = k * length + c: a scale (k) against a fixed end-point offset (c)
    k, c = robust_line(true, meas - true)
    # A scale error is read on the long pairs, where end-point noise is small against the length.
    long_pairs = sq >= LONG_SQUARES if np.sum(sq >= LONG_SQUARES) >= 10 else np.ones(len(sq), bool)
    err_long = err[long_pairs]
    frames_long = np.array([p.frame for p in pr])[long_pairs]
    spread = _frame_spread([p for p, keep in zip(pr, long_pairs) if keep])
    v = result.views
    ratio = _mean(x.depth_ratio for x in v)
    return {
        "board": {"squares": f"{result.board.squares_x}x{result.board.squares_y}",
                  "square_mm": result.board.square_m * 1000, "marker_mm": result.board.marker_m * 1000,
                  "dictionary": result.board.dictionary, "legacy": result.board.legacy,
                  "legacy_found": result.legacy_found},
        "frames": len(v) + len(result.missed_frames),
        "frames_with_board": len(v),
        "pairs": len(pr),
        "mean_accuracy": float(acc.mean()),
        "long_mean_accuracy": float(acc[long_pairs].mean()),
        "median_accuracy": float(np.median(acc)),
        # The median over the long pairs: short pairs on a contended patch of disparity have a heavy
        # tail that a mean follows, and end-point errors weigh most on them.
        "bias_pct": float(np.median(err_long)),
        "bias_se_pct": 1.2533 * _mad(err_long) / math.sqrt(n_eff),
        "bias_pairs": int(long_pairs.sum()),
        "mean_error_pct": float(err.mean()),
        "spread_pct": _mad(err),
        "scale_pct": float(100.0 * k),
        "offset_mm": float(1000.0 * c),
        "per_length": per_length,
        "good_share": float(np.mean([p.quality == "good" for p in pr])),
        "interval_coverage": float(np.mean([p.covered for p in pr])),
        # measured: 1.96 x the robust spread of the long pairs' errors, frame noise included
        "expected_pm_pct": 1.96 * _mad(err_long),
        "interval_pm_pct": float(np.median(half[long_pairs])),  # what the reported intervals claim
        "distance_m": _mean(x.distance_m for x in v),
        "tilt_deg": _mean(x.tilt_deg for x in v),
        "px_per_square": _mean(x.px_per_square for x in v),
        "fill_rate": _mean(x.fill_rate for x in v),
        "plane_rms_mm": _mm(_mean(x.plane_rms_m for x in v)),
        "plane_noise_mm": _mm(_mean(x.plane_noise_m for x in v)),
        "plane_noise_px": _mean(x.plane_noise_px for x in v),
        "outlier_share": _mean(x.outlier_share for x in v),
        "depth_vs_pose_pct": None if ratio is None else 100.0 * (ratio - 1.0),
        "disparity_px": _mean(x.disparity_px for x in v),
        "fx_baseline": result.fx_baseline,  # fx * B (px m) of the frames: depth = fx_baseline / disparity
        "frame_spread_mm": spread[0],
        "frame_spread_pct": spread[1],
        # per frame, the bias as above (median of the long pairs' errors)
        "frame_bias_pct": [float(np.median(err_long[frames_long == x.frame])) for x in v if np.any(frames_long == x.frame)],
    }


def _mad(v: np.ndarray) -> float:
    """1.4826 x the median absolute deviation: a standard deviation that a few wild values do not set."""
    return float(1.4826 * np.median(np.abs(v - np.median(v)))) if len(v) else math.nan


def _mm(m: float | None) -> float | None:
    return None if m is None else 1000.0 * m


def _frame_spread(pr: Sequence[PairResult]) -> tuple[float | None, float | None]:
    by_pair: dict[tuple[int, int], list[float]] = {}
    for p in pr:
        by_pair.setdefault((p.pair.id1, p.pair.id2), []).append(p.measured_m)
    stds = [(np.std(v, ddof=1), np.mean(v)) for v in by_pair.values() if len(v) >= 2]
    if not stds:
        return None, None
    return float(1000.0 * np.median([s for s, _ in stds])), float(100.0 * np.median([s / m for s, m in stds]))
