"""depthruler's measurement core: robust point-to-point 3D distance from registered disparity, and shapes
(a box's dimensions, a height above a plane, a path, an area) on robust planes.

Pure numpy/scipy; imports nothing else of ours, prints nothing, and does no I/O but its compiled
kernels' cache (``measure.aot``). ``__all__`` is the
public API (docs/api/measure.md); the submodules are internal and may change without notice.
"""

from measure.area import measure_area
from measure.box import measure_box
from measure.confidence import weak_stretches
from measure.distance import measure_distance
from measure.fields import Opt, OptionField, check as check_options, describe as describe_options, option, options_of
from measure.height import measure_height
from measure.metrics import accuracy, signed_error_pct
from measure.path import measure_path
from measure.robust import robust_with_terms
from measure.sampling import ray
from measure.sequence import MAX_FRAMES, measure_sequence
from measure.shape import measure_shape
from measure.options import METHODS
from measure.shape_types import SHAPE_KINDS, BoxMeasurement, ShapeMeasurement, outlines
from measure.types import MAX_CLICK_PX, Frame, MeasureError, MeasureOptions, Measurement, PinholeCamera
from measure.warm_up import warm_up
from measure.zonly import measure_z_only

__all__ = [
    "BoxMeasurement",
    "MAX_CLICK_PX",
    "MAX_FRAMES",
    "METHODS",
    "Opt",
    "OptionField",
    "Frame",
    "MeasureError",
    "MeasureOptions",
    "Measurement",
    "PinholeCamera",
    "SHAPE_KINDS",
    "ShapeMeasurement",
    "accuracy",
    "check_options",
    "describe_options",
    "measure_area",
    "measure_box",
    "measure_distance",
    "measure_height",
    "measure_path",
    "measure_sequence",
    "measure_shape",
    "measure_z_only",
    "option",
    "options_of",
    "outlines",
    "ray",
    "robust_with_terms",
    "signed_error_pct",
    "warm_up",
    "weak_stretches",
]
