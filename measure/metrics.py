"""How far a measured length is from the truth: the paper's accuracy (docs/method.md, Eq. 8) and the
signed relative error. Used by the evaluation, the board check and the tests alike."""

from __future__ import annotations

import numpy as np


def accuracy(truth_m: np.ndarray | float, measured_m: np.ndarray | float) -> np.ndarray:
    """Eq. 8: accuracy in percent points of measured lengths against true lengths (both metres, g > 0)."""
    g = np.asarray(truth_m, dtype=np.float64)
    m = np.asarray(measured_m, dtype=np.float64)
    return 100.0 - 100.0 * np.abs(g - m) / g


def signed_error_pct(truth_m: np.ndarray, measured_m: np.ndarray) -> np.ndarray:
    """Signed relative error 100 (m - g) / g in percent (positive = measured too long)."""
    g = np.asarray(truth_m, dtype=np.float64)
    return 100.0 * (np.asarray(measured_m, dtype=np.float64) - g) / g
