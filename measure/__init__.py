"""depthruler's measurement core: robust point-to-point 3D distance from registered disparity.

Pure numpy/scipy; imports nothing else of ours, prints nothing.
"""

from measure.distance import measure_distance
from measure.types import Frame, MeasureError, MeasureOptions, Measurement, PinholeCamera

__all__ = ["Frame", "MeasureError", "MeasureOptions", "Measurement", "PinholeCamera", "measure_distance"]
