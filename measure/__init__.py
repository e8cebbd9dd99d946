"""depthruler's measurement core: robust point-to-point 3D distance from registered disparity.

Pure numpy/scipy; imports nothing else of ours, does no I/O, prints nothing. ``__all__`` is the
public API (docs/api/measure.md); the submodules are internal and may change without notice.
"""

from measure.distance import measure_distance
from measure.metrics import accuracy, signed_error_pct
from measure.robust import robust_with_terms
from measure.sampling import ray
from measure.sequence import MAX_FRAMES, measure_sequence
from measure.types import MAX_CLICK_PX, Frame, MeasureError, MeasureOptions, Measurement, PinholeCamera
from measure.zonly import measure_z_only

__all__ = [
    "MAX_CLICK_PX",
    "MAX_FRAMES",
    "Frame",
    "MeasureError",
    "MeasureOptions",
    "Measurement",
    "PinholeCamera",
    "accuracy",
    "measure_distance",
    "measure_sequence",
    "measure_z_only",
    "ray",
    "robust_with_terms",
    "signed_error_pct",
]
