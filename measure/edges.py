"""Whether a click lies on a depth edge of the frame: a step in disparity just beyond it (px).

``on_edge``: any of the ``EDGE_PX`` pixels beyond the click (away from the other click) is more than
``EDGE_STEP`` (relative) off the click's disparity: the verdict's reason "end point on a depth edge".
``on_surface_edge``: most of the ``2 EDGE_PX + 1`` pixels beyond it are (scattered wrong matches are
not an edge): the robust method's test before it trusts a click window.
"""

from __future__ import annotations

from measure.sampling import valid_disparity
from measure.surfaces import on_depth_edge
from measure.types import Frame
from measure.verdict import EDGE_PX, EDGE_STEP


def on_edge(frame: Frame, start, other, d_end: float) -> bool:
    """Any of the EDGE_PX pixels beyond ``start`` (away from ``other``) on another surface than ``d_end`` (px)."""
    return on_depth_edge(frame.disparity, lambda v: valid_disparity(frame, v), start, other, float(d_end), EDGE_STEP, EDGE_PX)


def on_surface_edge(frame: Frame, start, other, d_end: float) -> bool:
    """Most of the 2 EDGE_PX + 1 pixels beyond ``start`` on another surface (scattered wrong matches are not an edge)."""
    return on_depth_edge(frame.disparity, lambda v: valid_disparity(frame, v), start, other, float(d_end), EDGE_STEP, 2 * EDGE_PX + 1, majority=True)
