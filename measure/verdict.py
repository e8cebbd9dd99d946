"""The quality verdict on an answer: "good", "check" or "unreliable", with short reasons.

"good" means: the truth is expected inside the stated 95 % interval and that interval is narrow
(half-width at most ``GOOD_HALF_WIDTH`` of the distance, i.e. one sigma at most 8 %). Any reason
below except the ``INFORMATIONAL`` ones makes an answer "check"; very few samples or an
interval wider than ``UNRELIABLE_HALF_WIDTH`` make it "unreliable". Why "end point on a depth edge"
and "end point extrapolated" only inform: an edge click is the robust method's normal case
(docs/decisions/verdict-reasons.md); "gap detected" informs because a gap answer's uncertainty is
that of its end surfaces and clicks (docs/decisions/gap-sigma.md).

Reasons (the phrases the CLI, API and page show):
- "few valid samples": fewer than ``FEW_SAMPLES`` valid samples along the segment, or fewer than
  ``FEW_SHARE`` of its pixels.
- "methods disagree by N %": the basic answer (window medians at the clicks) differs from this one by
  more than ``DISAGREE`` (relative).
- "end point on a depth edge": a depth step of more than ``EDGE_STEP`` within ``EDGE_PX`` px beyond a
  click (a mis-click of a pixel or two lands on another surface).
- "segment crosses several surfaces": the samples near an end disagree with the one-line model
  (``measure.surfaces``).
- "gap detected": the answer is measured across a gap (``measure.gap``), between the end surfaces.
- "low matcher confidence along the segment": the frame's confidence says the matcher had little
  support along the segment (``measure.confidence``).
- "end point extrapolated": an end is farther than ``EXTRAPOLATED_PX`` px (and 15 % of the length)
  from the nearest sample that supports its model, or has no depth at all.
- "uncertainty above N %": the interval's half-width exceeds ``GOOD_HALF_WIDTH``.
"""

from __future__ import annotations

FEW_SAMPLES = 20
FEW_SHARE = 0.5
UNRELIABLE_SAMPLES = 10
DISAGREE = 0.10
DISAGREE_CAP = 10.0  # 1000 %
EDGE_STEP = 0.1
EDGE_PX = 3
EXTRAPOLATED_PX = 5.0
GOOD_HALF_WIDTH = 0.24
UNRELIABLE_HALF_WIDTH = 0.5

QUALITIES: tuple[str, ...] = ("good", "check", "unreliable")
INFORMATIONAL: tuple[str, ...] = ("end point on a depth edge", "end point extrapolated", "gap detected")


def judge(reasons: list[str], n_valid: int | None, distance: float, half_width: float) -> tuple[str, tuple[str, ...]]:
    """Quality and reasons (``n_valid`` None: the method samples no segment); adds the "uncertainty above" reason from the interval's ``half_width`` (m)."""
    rel = half_width / distance if distance > 0 else float("inf")
    out = list(reasons)
    if not rel <= GOOD_HALF_WIDTH:
        out.append(f"uncertainty above {100 * GOOD_HALF_WIDTH:.0f} %")
    if (n_valid is not None and n_valid < UNRELIABLE_SAMPLES) or not rel <= UNRELIABLE_HALF_WIDTH:
        return "unreliable", tuple(out)
    demoting = [r for r in out if r not in INFORMATIONAL]
    return ("check" if demoting else "good"), tuple(out)


def disagreement(distance: float, other: float) -> str | None:
    """The "methods disagree" reason when ``other`` differs from ``distance`` by more than DISAGREE."""
    if not (other == other) or distance <= 0:  # NaN: the other method had no answer
        return None
    rel = abs(other - distance) / distance
    if rel > DISAGREE_CAP:  # beyond this the figure says nothing more, and 1e31 % says it badly
        return f"methods disagree by more than {100 * DISAGREE_CAP:.0f} %"
    return f"methods disagree by {100 * rel:.0f} %" if rel > DISAGREE else None
