"""How to measure: :class:`MeasureOptions`, each field's default, bounds, unit and help written once.

``METHODS`` is the one list of method names; the API schema (``GET /api/options``), the page, the
CLI help and the manual's option table (docs/usage.md) are made from it and from the fields'
metadata (:mod:`measure.fields`). Meaning of each option: docs/method.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from measure.errors import MeasureError
from measure.fields import check, option

METHODS: tuple[str, ...] = ("robust", "paper", "basic")
Method = str  # one of METHODS
MAX_CLICK_PX = 50.0  # a click's one-sigma error beyond this is no click on the object at all


def method_names() -> tuple[str, ...]:
    """The method names today (read when checked, so a method added to ``METHODS`` is accepted)."""
    return METHODS


@dataclass(frozen=True)
class MeasureOptions:
    """How to measure. See docs/method.md for the meaning of each parameter.

    Args:
        method: ``"robust"`` (robust disparity line along the segment, the default), ``"paper"``
            (the paper's robust 3D line, docs/method.md Eq. 3-7) or ``"basic"`` (window medians at the
            clicks and Eq. 2 only).
        support_fraction: fraction h/n of the samples FAST-MCD keeps (float in [0.5, 1.0]).
        window: side of the square window around each click (odd int from 1 to 51, px).
        extension_px: length of the extensions beyond the clicks that gap detection reads (int from 3
            to 500, px).
        gap_detection: whether to look for an end clicked on a depth gap (bool).
        seed: seed of FAST-MCD's random starts (int from 0 to 2**32 - 1); the same seed gives the same answer.
        click_px: one-sigma error of each click along the segment (float, px of the frame's image, from 0
            to ``MAX_CLICK_PX``): the uncertainty's click term (``measure.uncertainty.click_sigma``). The
            caller knows it: 0 for exact pixel coordinates (a program, detected corners, a replayed
            annotation), about 1.5 for a mouse (the default), more for a finger on a touch screen (its
            tap's error at the displayed scale, converted to image pixels). The calibration was set
            with the default, so values below 1 claim more than is measured
            (docs/decisions/uncertainty-calibration.md).

    Returns:
        Frozen, validated options; raises :class:`MeasureError` naming a value out of range.

    Examples:
        >>> from measure import MeasureOptions
        >>> opts = MeasureOptions(method="basic", window=7)
        >>> print(opts.method, opts.window, opts.support_fraction)
        basic 7 0.5
    """

    method: Method = option("robust", choices=method_names, help="robust: disparity line; paper: the paper's 3D line; basic: window medians")
    support_fraction: float = option(0.5, min=0.5, max=1.0, help="share h/n of the samples FAST-MCD keeps")
    window: int = option(5, min=1, max=51, odd=True, unit="px", help="side of the square window around each click")
    extension_px: int = option(25, min=3, max=500, unit="px", help="length of the extensions beyond the clicks that gap detection reads")
    gap_detection: bool = option(True, help="look for an end clicked on a depth gap and move it to the surface")
    seed: int = option(0, min=0, max=2**32 - 1, help="seed of FAST-MCD's random starts: the same seed gives the same answer")
    click_px: float = option(1.5, min=0.0, max=MAX_CLICK_PX, unit="px", help="one-sigma error of each click along the segment: 0 exact, 1.5 a mouse, more a finger")

    def __post_init__(self) -> None:
        check(self, MeasureError)
