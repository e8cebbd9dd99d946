"""Point-to-point 3D measurement: ``measure_distance`` and the registry of method implementations.

Inputs: a :class:`Frame` (disparity in px, intrinsics in px, baseline in m) and two clicked pixels
(x, y) of its colour image. Output: a :class:`Measurement` in metres (docs/method.md, Eq. 2-8).

Steps: validate the request (``measure.request``), read the click windows (``measure.basic.basic_ends``),
then hand the :class:`measure.request.Request` to the implementation of ``options.method`` in
``METHOD_IMPLEMENTATIONS``: ``basic`` (``measure.basic``: window medians, Eq. 2), ``paper``
(``measure.paper``: docs/method.md steps 1-6 as published) or ``robust`` (``measure.robust``, the
default). Adding a method is one module with a function ``Request -> Measurement`` and one line in
``METHOD_IMPLEMENTATIONS`` (docs/guides/measurement.md); its name is one of ``measure.types.METHODS``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

from measure.basic import basic_ends, measure_basic
from measure.paper import measure_paper
from measure.request import Request, validate_request
from measure.robust import measure_robust
from measure.types import Frame, MeasureOptions, Measurement

__all__ = ["METHOD_IMPLEMENTATIONS", "measure_distance"]

# One implementation per name of measure.types.METHODS (tests/measure/test_methods.py checks both lists agree).
METHOD_IMPLEMENTATIONS: Mapping[str, Callable[[Request], Measurement]] = {
    "robust": measure_robust,
    "paper": measure_paper,
    "basic": measure_basic,
}


def measure_distance(
    frame: Frame,
    p1: tuple[float, float],
    p2: tuple[float, float],
    options: MeasureOptions = MeasureOptions(),
) -> Measurement:
    """Distance (m) between clicked pixels ``p1`` and ``p2`` (x, y) of ``frame`` by ``options.method``.

    The robust and paper methods fit a robust model to the disparity sampled along the segment and
    back-project the clicks with it (docs/method.md, Eq. 2-7; the module docstring has the steps).

    Args:
        frame: colour image with registered disparity; its (H, W) float32 disparity is in px.
        p1: first click (x, y) (pair of floats, px, in the image of W x H).
        p2: second click (x, y) (px).
        options: method, window, support fraction, gap detection and seed.

    Returns:
        A :class:`Measurement`: ``distance_m`` and ``uncertainty_m`` in m, the 3D end points, the
        samples and the verdict.

    Raises:
        MeasureError: bad frame, clicks or options, clicks too close, or no valid disparity to measure from.

    Examples:
        >>> import numpy as np
        >>> from measure import Frame, PinholeCamera
        >>> cam = PinholeCamera(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
        >>> disparity = np.full((48, 64), 12.0, dtype=np.float32)  # a plane 0.5 m away
        >>> frame = Frame(np.zeros((48, 64, 3), np.uint8), disparity, cam, baseline_m=0.1)
        >>> from measure import MeasureOptions, measure_distance
        >>> m = measure_distance(frame, (10, 24), (54, 24))  # 44 px at 0.5 m with fx = 60 px
        >>> print(round(m.distance_m, 4), round(m.uncertainty_m, 4), m.fit, m.n_samples)
        0.3667 0.0247 constant-depth 45
        >>> print(round(measure_distance(frame, (10, 24), (54, 24), MeasureOptions(method="basic")).distance_m, 4))
        0.3667
    """
    t0 = time.perf_counter()
    xy1, xy2 = validate_request(frame, p1, p2, options)
    request = Request(frame, xy1, xy2, options, basic_ends(frame, xy1, xy2, options.window), t0)
    return METHOD_IMPLEMENTATIONS[options.method](request)
