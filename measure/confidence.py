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
