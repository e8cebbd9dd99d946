"""The shape options of ``depthruler measure``: a box, a height, a path or an area on one frame.

``--box X,Y`` (a click on a box's top face), ``--height X,Y`` (above the plane the clicked surface
stands on, or above the plane ``--on`` names: one click on it, or three or more around a region of
it), ``--path`` or ``--area`` with two or more / three or more ``--point X,Y`` clicks in order. The
answer is printed as text (value, one sigma, 95 % interval, verdict and reasons) or as JSON (the
result's ``to_dict`` with the source, frame and kind).
"""

from __future__ import annotations

import json
import math
from typing import Any

import typer

SHAPE_FLAGS = ("--box", "--height", "--path", "--area")


def shape_kind(box: str | None, height: str | None, path: bool, area: bool, points: list[str], on: list[str],
               segment: bool) -> str | None:
    """The kind the options ask for ("box", "height", "path", "area"), None for a segment; BadParameter
    when they ask for none, several, or give clicks that belong to another kind."""
    asked = [k for k, v in (("box", box), ("height", height), ("path", path), ("area", area)) if v]
    if segment:
        asked.append("segment")
    if len(asked) > 1:
        raise typer.BadParameter(f"choose one measurement, not {' and '.join(asked)}: --p1/--p2 (a segment), "
                                 + ", ".join(SHAPE_FLAGS))
    if not asked:
        raise typer.BadParameter("say what to measure: --p1 X,Y --p2 X,Y (a segment), --box X,Y, --height X,Y, "
                                 "--path or --area with --point X,Y clicks")
    kind = asked[0]
    if points and kind not in ("path", "area"):
        raise typer.BadParameter("--point clicks go with --path or --area", param_hint="--point")
    if on and kind != "height":
        raise typer.BadParameter("--on names the plane of a --height", param_hint="--on")
    return None if kind == "segment" else kind


def _m(v: float, unit: str = "m") -> str:
    return f"{v:.4f} {unit}" if math.isfinite(v) else "unknown"


def _verdict(quality: str, reasons: tuple[str, ...]) -> str:
    return f"quality: {quality.upper()}" + (f" ({'; '.join(reasons)})" if reasons else "")


def segment_text(result: Any, frames: int, frame: int) -> list[str]:
    """Text lines of a segment's answer measured on ``frames`` frames ending at ``frame``: the distance with
    one sigma and 95 % interval, the verdict, the fit, the basic estimate and, pooled, the gain over the
    newest frame alone; a value that is not finite reads "unknown", never "nan m"."""
    lo, hi = result.interval_m
    lines = [f"distance {_m(result.distance_m)}" + (f" ± {_m(result.uncertainty_m)}" if math.isfinite(result.uncertainty_m) else " (uncertainty unknown)"),
             f"95 % interval {lo:.4f} - {hi:.4f} m" if math.isfinite(lo) and math.isfinite(hi) else "95 % interval unknown",
             _verdict(result.quality, result.reasons),
             f"method {result.method}, fit {result.fit}, {result.n_support}/{result.n_valid} samples in support",
             f"basic estimate {_m(result.basic_distance_m)}" if math.isfinite(result.basic_distance_m)
             else "basic estimate: none (no depth within the window at an end point)"]
    if frames > 1:
        single, pooled = result.single_frame_uncertainty_m, result.uncertainty_m
        gain = f", {single / pooled:.2f}x narrower pooled" if math.isfinite(single) and math.isfinite(pooled) and pooled > 0 else ""
        lines.append(f"frames: {result.frames_used} of {frames} pooled (frames {frame - result.frames_used + 1}-{frame}); "
                     f"one sigma {_m(single)} on the newest frame alone{gain}")
    return lines


def shape_json(result: Any, kind: str, source: str, frame: int, truth: dict | None) -> str:
    """The JSON line: source, frame, kind and the result's fields (NaN as null)."""
    out: dict[str, Any] = {"source": source, "frame": frame, **result.to_dict(), "kind": kind}
    if truth:
        out["truth"] = truth
    return json.dumps(out)


def shape_text(result: Any, kind: str) -> list[str]:
    """Text lines: the value(s) with one sigma and 95 % interval, the verdict and its reasons."""
    if kind == "box":
        dims = ("length", "width", "height")
        lines = [f"box {' x '.join(f'{v:.4f}' for v in result.dimensions_m)} m (length x width x height)"]
        for name, v, s, (lo, hi) in zip(dims, result.dimensions_m, result.uncertainty_m, result.intervals_m):
            lines.append(f"{name} {_m(v)} ± {_m(s)}, 95 % interval {lo:.4f} - {hi:.4f} m")
        lines.append(_verdict(result.quality, result.reasons))
        lines.append(f"top face {result.n_top_px} px; corners (px) "
                     + " ".join(f"({x:.0f},{y:.0f})" for x, y in result.corners_px))
        return lines
    unit = "m²" if result.unit == "m2" else result.unit
    lo, hi = result.interval
    lines = [f"{kind} {_m(result.value, unit)} ± {_m(result.uncertainty, unit)}",
             f"95 % interval {lo:.4f} - {hi:.4f} {unit}" if math.isfinite(lo) and math.isfinite(hi) else "95 % interval unknown",
             _verdict(result.quality, result.reasons)]
    if result.parts:
        lines.append("legs " + ", ".join(f"{v:.4f} ± {s:.4f}" for v, s in zip(result.parts, result.part_sigmas)) + " m")
    return lines
