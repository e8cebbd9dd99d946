"""The check's verdict: measured conclusions from its figures, each with a likely cause and what to do.

:func:`findings` reads one check's figures (:func:`check.figures.figures`); :func:`trend_findings`
adds what earlier checks of the same camera and calibration at other distances tell (a bias that
grows with distance is a disparity offset, one that stays is a scale); :func:`status` sums them up
as "ok", "check" or "poor". How the figures separate the causes, and where the thresholds come
from: docs/decisions/check-verdict.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from check.advice import advice_for
from check.figures import LENGTH_BINS


@dataclass(frozen=True)
class Finding:
    """One conclusion: what was measured, its likely cause (an inference, not a measurement), what to do.
    severity: "info" | "warn" | "fail"."""

    measured: str
    cause: str = ""
    action: str = ""
    severity: str = "info"


# Thresholds of the verdict; where each comes from: docs/decisions/check-verdict.md, "Thresholds".
BIAS_PCT = 0.5
SHORT_A = 95.0  # a short length scoring below this (and 3 points below the long ones) is worth a word
LOW_A = 95.0  # long lengths below this: the check fails
FILL_LOW, FILL_OK = 0.5, 0.8
PLANE_RMS_PCT = 1.0
NOISE_PX = 0.5
OUTLIER_SHARE = 0.1
FAR_PM_PCT = 2.0
FAR_DISPARITY_PX = 25.0
SMALL_PX_PER_SQUARE = 15.0


def findings(fig: dict, kind: str | None = None) -> list[Finding]:
    """The verdict: measured conclusions, each with a likely cause and what to do (module docstring);
    ``kind``: the frames' source kind, which decides what fixes a scale (:func:`check.advice.advice_for`)."""
    advice = advice_for(kind)
    out: list[Finding] = []
    if fig["board"].get("legacy_found"):
        out.append(Finding(
            measured="the board's markers were found but no corners with the board as described; its corners were "
                     "with OpenCV's legacy pattern",
            cause="the board was printed by OpenCV before 4.6 or a generator that follows it (an even number of rows)",
            action="pass --legacy to check and calibrate with this board",
            severity="info",
        ))
    z = fig["distance_m"] or math.nan
    b, se = fig["bias_pct"], fig["bias_se_pct"]
    sq_mm = fig["board"]["square_mm"]
    if abs(b) >= BIAS_PCT and abs(b) > 3 * se:
        biases = [v["bias_pct"] for v in fig["per_length"].values() if v["n"] >= 3]
        tol = max(BIAS_PCT, 0.35 * abs(b))
        # a scale: the robust slope says the same as the median, and the bias is no end-point offset
        # (the 2-square and longer bins agree; one-square pairs are too noisy to judge)
        firm = [v["bias_pct"] for key, v in fig["per_length"].items() if v["n"] >= 3 and key != LENGTH_BINS[0][2]]
        bins_agree = abs(fig["scale_pct"] - b) <= tol and all(abs(x - b) <= tol for x in firm)
        dz = fig["depth_vs_pose_pct"]
        depth_agrees = dz is not None and abs(dz - b) <= tol  # the pose does not use the baseline
        word = "long" if b > 0 else "short"
        span = f" ({min(biases):+.1f} to {max(biases):+.1f} % across lengths)" if biases else ""
        measured = f"lengths read {abs(b):.1f} % {word} at {z:.1f} m ({fig['bias_pairs']} long pairs, ±{1.96 * se:.1f} %){span}"
        if depth_agrees:
            out.append(Finding(
                measured=measured + f"; stereo depth reads {dz:+.1f} % against the board's pose from the image alone"
                         + (" - the same at every length: a scale error" if bins_agree else ": a scale error"),
                cause=advice.scale_cause.format(pct=b) + " (it scales every depth and length alike, and the pose does "
                      "not use it); a board printed at another scale than --square-mm gives the same signature",
                action=f"measure a printed square with a ruler: if it is {sq_mm:g} mm, "
                       + advice.scale_action.format(factor=1 / (1 + b / 100)) + "; otherwise pass the measured --square-mm",
                severity="fail" if abs(b) >= 2.0 else "warn",
            ))
        elif bins_agree:
            out.append(Finding(
                measured=measured + f" - the same at every length, but stereo depth agrees with the board's pose "
                         f"({dz:+.1f} %)" if dz is not None else measured,
                cause="a scale in the lengths that depth does not share: not the baseline; the corner positions or the "
                      "measurement method",
                action="check the image is sharp and the board flat; report it with the check's PNG",
                severity="warn",
            ))
        else:
            out.append(Finding(
                measured=measured + f"; the error is mostly a fixed {fig['offset_mm']:+.1f} mm per length, not a scale",
                cause="the end points are pulled (disparity smoothing or edge fattening at the corners, "
                      "or a detection offset), which matters most on short lengths",
                action="expect short measurements to be off by that much; check focus and the disparity filter settings",
                severity="warn",
            ))
    fill = fig["fill_rate"]
    if fill is not None and fill < FILL_OK:
        out.append(Finding(
            measured=f"fill rate {100 * fill:.0f} %: that share of the board has valid disparity",
            cause="too little light or texture for the stereo matcher (the board's plain squares and margins)",
            action="add light or texture (switch on the IR projector if the camera has one)",
            severity="warn" if fill < FILL_LOW else "info",
        ))
    pm = fig["expected_pm_pct"]
    d = fig["disparity_px"]
    if pm > FAR_PM_PCT or (d is not None and d < FAR_DISPARITY_PX and pm > 1.0):
        closer = z / pm if math.isfinite(z) and pm > 0 else math.nan  # the error grows about with distance
        out.append(Finding(
            measured=f"95 % of long lengths fall within ±{pm:.1f} % of the truth at {z:.1f} m (disparity {d:.0f} px on the board)",
            cause=f"the board is far for this baseline: a quarter-pixel matching error is {25 / d:.1f} % of depth there"
                  if d and math.isfinite(d) else "the board is far for this baseline",
            action=f"expect ±{pm:.1f} % at this distance" + (f"; for about ±1 % measure within {closer:.1f} m" if pm > 1 else ""),
            severity="info",
        ))
    px = fig["px_per_square"]
    if px is not None and px < SMALL_PX_PER_SQUARE:
        out.append(Finding(
            measured=f"the board's squares are {px:.0f} px wide in the image",
            cause="corners of a small board are found less precisely, which adds error to every pair",
            action="move closer or print a larger board (depthruler calibrate --board-png)",
            severity="warn",
        ))
    noise, rms, outl = fig["plane_noise_mm"], fig["plane_rms_mm"], fig["outlier_share"]
    if noise is not None and math.isfinite(z) and noise / (10 * z) > PLANE_RMS_PCT:
        noisy = fig["plane_noise_px"] > NOISE_PX
        out.append(Finding(
            measured=f"depth noise {noise:.1f} mm ({noise / (10 * z):.1f} % of the distance, {fig['plane_noise_px']:.2f} px "
                     "of disparity) about the flat board's plane",
            cause="noisy matching: low light, a weakly textured or shiny board, or a bent board" if noisy else
                  "the distance: the matching itself is precise, but a fraction of a pixel is a lot of depth this far",
            action="improve the light, flatten the board, or move closer" if noisy else "move closer for less depth noise",
            severity="warn" if noisy else "info",
        ))
    if outl is not None and outl > OUTLIER_SHARE:
        out.append(Finding(
            measured=f"{100 * outl:.0f} % of the board's depth is more than 3 sigma off its plane "
                     f"(plane-fit RMS {rms:.1f} mm against {noise:.1f} mm noise)",
            cause="wrong stereo matches (repetitive or plain areas, reflections); the robust method rejects most of them",
            action="expect single clicks on such patches to be off; more texture or light helps",
            severity="info",
        ))
    cov = fig["interval_coverage"]
    if cov < 0.8:
        out.append(Finding(
            measured=f"the true length fell inside the reported 95 % interval for {100 * cov:.0f} % of pairs",
            cause="the intervals do not cover this camera's errors" + (" (the bias above is not in them)" if any(
                f.severity != "info" and "lengths read" in f.measured for f in out) else ""),
            action="fix the bias first; until then read the ± as a lower bound",
            severity="warn",
        ))
    sp = fig["frame_spread_pct"]
    if sp is not None and sp > 2 * pm / 1.96:  # clearly more than the noise within one frame
        out.append(Finding(
            measured=f"a length varies by {sp:.2f} % (1 sigma) from frame to frame",
            cause="the camera or board moved, or the light flickers",
            action="hold camera and board still; measure on a frozen frame",
            severity="info",
        ))
    short = fig["per_length"].get(LENGTH_BINS[0][2])
    long_a = fig["long_mean_accuracy"]
    if short and short["mean_accuracy"] < min(SHORT_A, long_a - 3.0):
        px_short = fig["px_per_square"]
        out.append(Finding(
            measured=f"short lengths (1 square, {px_short:.0f} px) score A {short['mean_accuracy']:.1f} "
                     f"(bias {short['bias_pct']:+.1f} %) against {long_a:.1f} for 3 squares or more",
            cause="a short segment holds few disparity samples, and each end's depth error is a large share of it",
            action="measure objects that span 100 px or more in the image: move closer for small ones",
            severity="warn",
        ))
    if long_a < LOW_A and not any(f.severity == "fail" for f in out):
        out.append(Finding(measured=f"even lengths of 3 squares or more score only A {long_a:.1f}", severity="fail",
                           cause="see the findings above (light, texture, distance)",
                           action="fix those, then check again"))
    return out


TREND_MIN_CHECKS = 3
TREND_MIN_RATIO = 1.5  # farthest / nearest distance among the checks


def trend_findings(history: Sequence[dict], fig: dict, kind: str | None = None) -> list[Finding]:
    """What the earlier checks of the same camera and calibration add (``history``: their records with
    "figures"): whether the bias stays the same across distances (a baseline: ``Z = fx B / d`` scales
    every distance alike) or grows with distance (a disparity offset delta: the relative error of
    ``fx B / (d + delta)`` is about ``-delta / d = -delta Z / (fx B)``, proportional to Z); ``kind``: the
    frames' source kind, which decides the words (:func:`check.advice.advice_for`)."""
    advice = advice_for(kind)
    pts = [(h["figures"].get("distance_m"), h["figures"].get("bias_pct"), h["figures"].get("fx_baseline"))
           for h in history if h.get("figures")] + [(fig["distance_m"], fig["bias_pct"], fig["fx_baseline"])]
    pts = [p for p in pts if all(v is not None and math.isfinite(v) for v in p)]
    if len(pts) < TREND_MIN_CHECKS:
        return []
    z, bias, fxb = (np.array(v, np.float64) for v in zip(*pts))
    if z.max() / z.min() < TREND_MIN_RATIO:
        return []
    slope, icpt = np.polyfit(z, bias, 1)
    change = slope * (z.max() - z.min())
    where = f"{len(pts)} checks from {z.min():.1f} to {z.max():.1f} m"
    if abs(change) >= BIAS_PCT:
        delta = -slope * float(np.median(fxb)) / 100.0
        return [Finding(
            measured=f"over {where} the bias goes from {icpt + slope * z.min():+.1f} to {icpt + slope * z.max():+.1f} %: "
                     "it grows with distance",
            cause=advice.offset_cause.format(delta=delta),
            action=advice.offset_action,
            severity="warn",
        )]
    if abs(float(np.mean(bias))) >= BIAS_PCT:
        return [Finding(
            measured=f"over {where} the bias stays at {np.mean(bias):+.1f} % (±{abs(change) / 2:.1f})",
            cause="a scale that does not depend on distance: " + ("the baseline (or the board's printed size), not a "
                  "disparity offset" if advice.family == "stereo" else "the camera's depth scale (or the board's printed "
                  "size), not an offset"),
            action="see the scale finding above: " + advice.scale_action.format(factor=1 / (1 + float(np.mean(bias)) / 100)),
            severity="info",
        )]
    return []


def status(found: Sequence[Finding]) -> str:
    """"ok" (nothing to act on), "check" (a warning) or "poor" (a failing figure)."""
    severities = {f.severity for f in found}
    return "poor" if "fail" in severities else "check" if "warn" in severities else "ok"
