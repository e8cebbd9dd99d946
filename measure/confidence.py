"""What the matcher's confidence (``Frame.confidence``, 0 = no support, 1 = fully supported) says about
a segment: the verdict's "low matcher confidence" reason and the fit's effective sample size.

- ``low_confidence``: the mean confidence of the segment's valid samples is below ``LOW_CONFIDENCE``.
  For SGBM sources the confidence is the texture term ``1 - noise / gradient energy``
  (``device.sources.sgbm.texture_confidence``), so 0.5 is a signal-to-noise ratio of one: along such a
  segment SGBM's smoothness, not the images, chose most disparities, and a smooth, dense map can be
  wrong by pixels with nothing in its residuals to show it.
- ``support_inflation``: factor on the fit's standard errors, sqrt(n / sum(c)) over the n supporting
  samples (the confidences as information weights: n_eff = sum(c)), at most sqrt(n) (one sample's worth).

Frames without confidence, or with 1 on every valid pixel, are unchanged by both.
Why and the measurement: docs/decisions/matcher-confidence.md.
"""

from __future__ import annotations

import math

import numpy as np

from measure.sampling import segment_pixels

LOW_CONFIDENCE = 0.5
LOW_CONFIDENCE_REASON = "low matcher confidence along the segment"


def low_confidence(confidence: np.ndarray | None) -> bool:
    """The mean of ``confidence`` (the valid samples' values in [0, 1]) is below LOW_CONFIDENCE."""
    if confidence is None or confidence.size == 0:
        return False
    return float(np.mean(confidence)) < LOW_CONFIDENCE


def support_inflation(confidence: np.ndarray | None, support: np.ndarray) -> float:
    """sqrt(n / sum(c)) over the supporting samples (>= 1, at most sqrt(n)); 1 without confidence."""
    if confidence is None:
        return 1.0
    c = np.clip(np.asarray(confidence, dtype=np.float64)[support], 0.0, 1.0)
    n = int(c.size)
    if n == 0:
        return 1.0
    return math.sqrt(n / max(float(c.sum()), 1.0))


WEAK_WINDOW_PX = 5  # segment pixels the confidence is averaged over before the LOW_CONFIDENCE threshold


def weak_stretches(
    confidence: np.ndarray | None, p1: tuple[float, float], p2: tuple[float, float]
) -> np.ndarray:
    """Where along the segment ``p1`` -> ``p2`` the matcher's support is weak, as fractions of it.

    Steps: the segment's pixels (``measure.sampling.segment_pixels``, one per column or row), their
    confidence (NaN counts as 0: no support), its mean over ``WEAK_WINDOW_PX`` consecutive pixels
    (fewer at the ends), and the runs where that mean is below ``LOW_CONFIDENCE``, the threshold of the
    verdict's "low matcher confidence" reason. Every pixel is counted, with or without disparity: the
    reason reads only the valid samples' mean, so a mostly supported segment can still have a weak
    stretch. Each run spans its pixels' cells (half a pixel step either side), so a segment weak from
    end to end is ``[[0, 1]]``.

    Args:
        confidence: the frame's (H, W) confidence in [0, 1] (``Frame.confidence``), or None.
        p1: first click (x, y) (px, inside the image).
        p2: second click (x, y) (px).

    Returns:
        (k, 2) float64 array of ``[t0, t1]`` with 0 <= t0 < t1 <= 1, in order, as fractions of the
        segment's length (0 = ``p1``, 1 = ``p2``); (0, 2) without confidence or without a weak run.

    Examples:
        >>> c = np.ones((10, 20), np.float32); c[:, 10:] = 0.1   # the right half has no texture
        >>> weak_stretches(c, (0.0, 5.0), (19.0, 5.0)).round(3).tolist()
        [[0.5, 1.0]]
        >>> weak_stretches(None, (0.0, 5.0), (19.0, 5.0)).shape
        (0, 2)
    """
    none = np.zeros((0, 2), np.float64)
    if confidence is None:
        return none
    px = segment_pixels(p1[0], p1[1], p2[0], p2[1])
    n = len(px)
    c = np.nan_to_num(np.asarray(confidence)[px[:, 1], px[:, 0]].astype(np.float64), nan=0.0)
    kernel = np.ones(min(WEAK_WINDOW_PX, n))
    local = np.convolve(c, kernel, mode="same") / np.convolve(np.ones(n), kernel, mode="same")
    weak = local < LOW_CONFIDENCE
    if not weak.any():
        return none
    edges = np.diff(np.concatenate(([0], weak.astype(np.int8), [0])))
    first, last = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    # pixel i's cell along the segment: from its step's start to its end, in fractions of the pixel run
    step = 1.0 / max(n - 1, 1)
    t = np.stack([first * step - step / 2, last * step + step / 2], axis=1)
    return np.clip(t, 0.0, 1.0) if n > 1 else np.array([[0.0, 1.0]])
