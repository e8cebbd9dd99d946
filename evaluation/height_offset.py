"""The height's error on the simulated rig split into the frame's disparity offset and the rest.

The shapes study's height cases (``evaluation.shapes``: ``sim.shapes.box_case`` boxes whose top is
fully seen, 1-3 m from the camera, the click on the top, ``measure.height.measure_height`` with no
base) are measured twice: on the frame as drawn, and on the same frame with the disparity offset
drawn for it (``meta["calibration_offset_px"]``, the paper profile's calibration error) subtracted
from every pixel. The second answer's error is what the rest of the method leaves (integer levels,
the planes' fits, wrong supports); the difference of the two is the offset's share, which no fit
on one frame sees (docs/decisions/height-offset-bound.md).

    python -m evaluation.height_offset --seed 0 --boxes 200      # the shapes report's seeds
    python -m evaluation.height_offset --seed 1000 --boxes 200   # held out
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from typing import Any

import numpy as np

from evaluation.shapes import FULL_VIEW, HEIGHT_BAND

OFFSET_KEY = "calibration_offset_px"


def height_case(seed: int, profile: str = "paper") -> dict[str, Any] | None:
    """The record of box case ``seed`` (errors in %, offset in px), or None when it is not a height
    case of the shapes study (top not fully seen, or outside 1-3 m)."""
    from measure import MeasureError, measure_height
    from sim.sensor import clear_static_maps
    from sim.shapes import box_case

    try:
        case = box_case(seed, profile)
    finally:
        clear_static_maps()
    if case.visible < FULL_VIEW or not HEIGHT_BAND[0] <= case.range_m < HEIGHT_BAND[1]:
        return None
    offset = float(case.frame.meta.get(OFFSET_KEY, 0.0))
    calibrated = replace(case.frame, disparity=(case.frame.disparity - np.float32(offset)).astype(np.float32))
    rec: dict[str, Any] = {"seed": seed, "range_m": case.range_m, "offset_px": offset}
    for key, frame in (("drawn", case.frame), ("calibrated", calibrated)):
        try:
            m = measure_height(frame, case.click_px)
            rec[f"{key}_err_pct"] = 100.0 * (m.value - case.height_m) / case.height_m
            rec[f"{key}_z"] = abs(m.value - case.height_m) / m.uncertainty
        except MeasureError:
            rec[f"{key}_err_pct"] = rec[f"{key}_z"] = math.nan
    rec["offset_share_pct"] = rec["drawn_err_pct"] - rec["calibrated_err_pct"]
    h = exact_height(case.frame, case.click_px, case.support_plane, case.height_m, offset)
    rec["exact_err_pct"] = 100.0 * (h - case.height_m) / case.height_m
    return rec


def exact_height(frame, click: tuple[float, float], base: tuple[float, float, float, float], height_m: float,
                 offset_px: float) -> float:
    """Height (m) of the click's point on the true top plane above the true base plane (``base``: n . P + o = 0,
    camera frame, n towards the camera; the top ``height_m`` above it), both seen through a disparity offset
    of ``offset_px``: each plane's Eq. 9 coefficients with the offset added to gamma, read back as Eq. 10."""
    cam = frame.camera
    fb = cam.fx * frame.baseline_m
    n = np.array(base[:3], float)

    def coeffs(o: float) -> np.ndarray:  # Eq. 10 solved for Eq. 9's (alpha, beta, gamma), doffs 0, plus the offset
        a, b = -n[0] * fb / (o * cam.fx), -n[1] * fb / (o * cam.fy)
        return np.array([a, b, -n[2] * fb / o - a * cam.cx - b * cam.cy - frame.doffs + offset_px])

    x, y = click
    top, bottom = coeffs(base[3] - height_m), coeffs(base[3])
    z = fb / (top @ (x, y, 1.0) + frame.doffs)
    p = np.array([(x - cam.cx) * z / cam.fx, (y - cam.cy) * z / cam.fy, z])
    a, b, g = bottom
    m = np.array([a * cam.fx, b * cam.fy, a * cam.cx + b * cam.cy + g + frame.doffs])
    return float(-(m @ p) / np.linalg.norm(m) + fb / np.linalg.norm(m))


def summarize(records: list[dict[str, Any]]) -> dict[str, float]:
    """Median |error| (%) as drawn, with the offset subtracted, of the offset's share and of the true planes
    through the offset alone; 2σ coverage
    as drawn; the median |offset| (px); answered and refused counts."""
    def med(key: str) -> float:
        x = np.array([r[key] for r in records], float)
        x = x[np.isfinite(x)]
        return float(np.median(np.abs(x))) if x.size else math.nan

    z = np.array([r["drawn_z"] for r in records], float)
    return {"n": len(records), "refused": int(np.isnan([r["drawn_err_pct"] for r in records]).sum()),
            "drawn_pct": med("drawn_err_pct"), "calibrated_pct": med("calibrated_err_pct"),
            "offset_share_pct": med("offset_share_pct"), "exact_pct": med("exact_err_pct"), "offset_px": med("offset_px"),
            "coverage_2sigma": float(np.mean(z[np.isfinite(z)] <= 2.0)) if np.isfinite(z).any() else math.nan}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="first box seed (default 0)")
    ap.add_argument("--boxes", type=int, default=200, help="box seeds to draw (default 200, as the shapes report)")
    ap.add_argument("--profile", default="paper", help="simulator profile (default paper)")
    args = ap.parse_args(argv)
    recs = [r for s in range(args.seed, args.seed + args.boxes) if (r := height_case(s, args.profile)) is not None]
    s = summarize(recs)
    print(f"{args.profile}, box seeds {args.seed}-{args.seed + args.boxes - 1}: {s['n']} height cases at 1-3 m, "
          f"{s['refused']} refused; median |offset| {s['offset_px']:.3f} px")
    print("| height median abs. error 1-3 m | % |\n| --- | --- |")
    print(f"| as drawn | {s['drawn_pct']:.3f} |\n| drawn offset subtracted | {s['calibrated_pct']:.3f} |\n"
          f"| the offset's share (difference) | {s['offset_share_pct']:.3f} |\n"
          f"| true planes through the drawn offset, nothing else | {s['exact_pct']:.3f} |")
    print(f"2σ coverage as drawn: {100 * s['coverage_2sigma']:.1f} %")


if __name__ == "__main__":
    main()
