"""The paper's end-point projections (docs/method.md steps 3-4). Metres, camera frame.

Both broadcast over leading axes so the uncertainty code can evaluate many perturbed models
at once. (The robust method instead takes the end points on the clicks' viewing rays; see
``measure.dline``.)
"""

from __future__ import annotations

import numpy as np


def project_on_line(p: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Eq. 6-7: perpendicular projection of P onto the line T + s v (v unit)."""
    return t + np.sum((p - t) * v, axis=-1, keepdims=True) * v


def project_on_plane(p: np.ndarray, plane: tuple[float, float, float, float]) -> np.ndarray:
    """Eq. 4-5: perpendicular projection of P onto a X + b Y + c Z + d = 0."""
    n = np.asarray(plane[:3], dtype=np.float64)
    t = -(p @ n + plane[3]) / (n @ n)
    return p + np.asarray(t)[..., None] * n
