"""The stream side of `depthruler doctor`: open the source, read it for a window, and judge what arrived.

Frames are read as fast as the source gives them for ``window_s`` seconds (host clock); the doctor keeps
every frame's arrival time and timestamp, the first frame and the last few (for the fill rate and the
board check). The thresholds below are what a measurement needs, not what a camera promises: a
click needs depth under it (fill), and measuring over frames needs frames in order (timestamps).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from device import Source, SourceInfo
from device.errors import SourceEnded, SourceError, SourceTimeout
from measure import Frame

from check.doctor.findings import Finding

FPS_SHARE_WARN = 0.8  # delivered below 80 % of the source's own rate: frames are being lost on the way
FILL_WARN, FILL_FAIL = 0.6, 0.3  # share of pixels with depth in the centre of the view
DROP_GAP = 1.5  # a timestamp step over 1.5 x the due step counts as dropped frames


@dataclass(frozen=True)
class Window:
    """What one read window delivered: host arrival times (s, monotonic), frame timestamps (s), the first
    frame and the last ``keep`` frames, whether the source ended (a file), timeouts, and why it stopped."""

    info: SourceInfo
    arrivals: tuple[float, ...]
    timestamps: tuple[float, ...]
    first: Frame | None
    last: tuple[Frame, ...]
    window_s: float
    ended: bool = False
    timeouts: int = 0
    error: str = ""

    @property
    def n(self) -> int:
        return len(self.arrivals)


def read_window(src: Source, window_s: float, *, keep: int = 3, timeout_s: float = 2.0,
                clock: Callable[[], float] = time.monotonic) -> Window:
    """Read ``src`` (open) for ``window_s`` seconds, or until it ends or disconnects."""
    arrivals: list[float] = []
    stamps: list[float] = []
    last: deque[Frame] = deque(maxlen=keep)
    first = None
    ended, timeouts, error = False, 0, ""
    t0 = clock()
    while clock() - t0 < window_s:
        try:
            frame = src.read(timeout_s)
        except SourceEnded:
            ended = True
            break
        except SourceTimeout:
            timeouts += 1
            continue
        except SourceError as exc:  # disconnected mid-window: what arrived is still judged
            error = str(exc)
            break
        arrivals.append(clock() - t0)
        stamps.append(float(frame.timestamp))
        first = first or frame
        last.append(frame)
    return Window(src.info, tuple(arrivals), tuple(stamps), first, tuple(last), window_s, ended, timeouts, error)


def _slow_fix(kind: str) -> str:
    return {
        "oak": "use a USB3 port and cable, lower fps= or the size, and close other programs using the OAK",
        "v4l2": "ask the camera for MJPEG at this size, lower size= or scale=, or ndisp= (SGBM's cost grows with it)",
        "bag": "the bag is read as fast as it decodes; nothing to fix unless it is far below the recorded rate",
        "replay": "the recording is read as fast as its PNGs decode: expect it on a slow host",
    }.get(kind, "the host computes frames slower than this rate: lower width=/height= (or scale=), or expect it")


def frames_finding(w: Window) -> Finding:
    """"frames": did frames arrive, and at what rate (host clock) against the source's own rate."""
    kind, nominal = w.info.kind, float(w.info.fps or 0.0)
    if w.n == 0:
        why = w.error or ("the source ended before the first frame" if w.ended else f"{w.timeouts} read(s) timed out")
        return Finding("frames", "fail", f"no frame in {w.window_s:g} s: {why}",
                       "check the cable and that no other program holds the camera; run `depthruler devices`",
                       {"frames": 0, "fps": 0.0, "timeouts": w.timeouts})
    span = w.arrivals[-1] - w.arrivals[0]
    fps = (w.n - 1) / span if w.n > 1 and span > 0 else math.nan
    figures = {"frames": w.n, "fps": None if math.isnan(fps) else fps, "nominal_fps": nominal or None,
               "timeouts": w.timeouts, "ended": w.ended}
    over = f"{w.n} frames in {w.arrivals[-1]:.1f} s" + (" (the file ended)" if w.ended else "")
    rate = "one frame, no rate" if math.isnan(fps) else f"{fps:.1f} fps delivered"
    rate += f" against {nominal:g} fps nominal" if nominal else " (the source sets no rate: as fast as read)"
    measured = f"{over}: {rate}" + (f"; {w.timeouts} read(s) timed out" if w.timeouts else "")
    if w.error:
        return Finding("frames", "fail", f"{measured}; then: {w.error}", "replug the camera and run the doctor again", figures)
    if nominal and not math.isnan(fps) and fps < FPS_SHARE_WARN * nominal:
        return Finding("frames", "warn", measured, _slow_fix(kind), figures)
    if w.timeouts:
        return Finding("frames", "warn", measured, "frames stall now and then: " + _slow_fix(kind), figures)
    return Finding("frames", "pass", measured, "", figures)


def timestamps_finding(w: Window) -> Finding:
    """"timestamps": strictly increasing (measuring over frames pools them in order), steps even (no drops)."""
    t = np.asarray(w.timestamps, np.float64)
    if t.size < 2:
        return Finding("timestamps", "skip", f"{t.size} frame(s): no timestamp steps to judge")
    steps = np.diff(t)
    back, same = int(np.sum(steps < 0)), int(np.sum(steps == 0))
    pos = steps[steps > 0]
    median = float(np.median(pos)) if pos.size else math.nan
    # a frame is due at the source's own rate; a source that states none (as fast as read) drops nothing
    due = 1.0 / w.info.fps if w.info.fps else math.inf
    dropped = int(np.sum(np.maximum(np.round(pos / due) - 1, 0)[pos > DROP_GAP * due])) if pos.size else 0
    figures = {"frames": int(t.size), "backwards": back, "repeated": same, "median_step_s": None if math.isnan(median) else median,
               "device_fps": None if math.isnan(median) else 1.0 / median, "dropped": dropped}
    rate = f", steps of {1000 * median:.1f} ms ({1 / median:.1f} fps on the device clock)" if pos.size else ""
    drops = f"{dropped} frame(s) dropped" if w.info.fps else "no rate stated, so no drops to count"
    measured = f"{t.size} timestamps: {back} step(s) backwards, {same} repeated{rate}, {drops}"
    if float(np.ptp(t)) == 0.0:
        return Finding("timestamps", "warn", f"all {t.size} timestamps are {t[0]:g}: the source gives none",
                       "the frames cannot be told apart in time; record with a source that stamps them", figures)
    if back:
        return Finding("timestamps", "fail", measured, "the clock jumps back (a reset, or frames out of order): replug the camera; "
                       "for a recording, re-record it (frames.jsonl must be in time order)", figures)
    if same:
        return Finding("timestamps", "warn", measured, "repeated timestamps: the source sends a frame twice", figures)
    if dropped > 0.05 * t.size:
        fix = ("the recording has gaps: it was written slower than its source's rate; record again at a lower fps= or size"
               if w.info.kind == "replay" else "frames are dropped on the way: " + _slow_fix(w.info.kind))
        return Finding("timestamps", "warn", measured, fix, figures)
    return Finding("timestamps", "pass", measured, "", figures)


def shape_finding(w: Window) -> Finding:
    """"registration": the depth is registered to the image (same size as the image and the intrinsics)."""
    f = w.first
    if f is None:
        return Finding("registration", "skip", "no frame")
    img, disp, cam = f.image.shape[:2], f.disparity.shape, f.camera
    measured = f"image {img[1]}x{img[0]}, depth {disp[1]}x{disp[0]}, intrinsics for {cam.width}x{cam.height}"
    if img != disp or (cam.height, cam.width) != img:
        return Finding("registration", "fail", measured, "the depth must be registered to the image it is clicked on: use the "
                       "source's align option, or a calibration made at this image size", {"image": list(img), "depth": list(disp)})
    return Finding("registration", "pass", measured, "", {"image": [img[1], img[0]]})


def fill_finding(w: Window) -> Finding:
    """"fill": share of pixels with depth on the current view (the last frame), whole and the centre half."""
    if not w.last:
        return Finding("fill", "skip", "no frame")
    f = w.last[-1]
    ok = np.isfinite(f.disparity) & (f.disparity + f.doffs > 0)
    h, wd = ok.shape
    centre = ok[h // 4: h - h // 4, wd // 4: wd - wd // 4]
    whole, mid = float(ok.mean()), float(centre.mean())
    depth = f.depth()[ok]
    median_z = float(np.median(depth)) if depth.size else math.nan
    # one disparity pixel at the median depth, in mm: dZ = Z^2 / (fx B)
    step_mm = 1000 * median_z**2 / (f.camera.fx * f.baseline_m) if depth.size and f.baseline_m > 0 else math.nan
    figures = {"fill_rate": whole, "centre_fill_rate": mid, "median_depth_m": None if math.isnan(median_z) else median_z,
               "mm_per_disparity_px": None if math.isnan(step_mm) else step_mm}
    measured = f"{100 * whole:.0f} % of pixels have depth ({100 * mid:.0f} % in the centre)"
    if depth.size:
        measured += f"; median depth {median_z:.2f} m, where 1 px of disparity is {step_mm:.1f} mm"
    fix = ("point the camera at a textured, lit scene between its near and far limits; for a stereo pair check "
           "ndisp= covers the nearest object and the calibration rectifies (flat depth = rows do not line up)")
    status = "fail" if mid < FILL_FAIL else "warn" if mid < FILL_WARN else "pass"
    return Finding("fill", status, measured, "" if status == "pass" else fix, figures)
