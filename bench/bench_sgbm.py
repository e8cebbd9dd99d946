"""SGBM throughput per mode, with and without WLS, at 640x480 and 1280x720, against StereoBM.

Run: ``.venv/bin/python bench/bench_sgbm.py [--write]``. Frames are a real Middlebury pair
(Motorcycle) resized to each size; 64 disparities, block 5. Each configuration is timed with the
StereoBM reference interleaved in the same process, so the ratio column survives a busy machine
better than the fps column. ``--write`` replaces the "## SGBM" section of bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from device.calibration.stereo import StereoCalibration  # noqa: E402
from device.sources.sgbm import SGBMConfig, compute_disparity  # noqa: E402
from bench.results_file import cpu_name, replace_section  # noqa: E402
from device.sources.stereo_processing import StereoProcessor  # noqa: E402
from evaluation.middlebury_data import default_data_dir  # noqa: E402

SCENE = default_data_dir() / "Motorcycle"
SIZES = ((640, 480), (1280, 720))
MODES = ("sgbm", "sgbm_3way", "hh", "hh4")


def bm_reference(left: np.ndarray, right: np.ndarray) -> None:
    gl, gr = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
    cv2.StereoBM.create(numDisparities=64, blockSize=15).compute(gl, gr)


def timed(fn, repeats: int) -> float:
    """Median wall seconds per call after one warm-up call."""
    return timed_cpu(fn, repeats)[0]


def timed_cpu(fn, repeats: int) -> tuple[float, float]:
    """Median wall and process-CPU seconds per call (CPU summed over threads; waiting for a busy
    machine's cores shows in wall time but not in CPU time)."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return float(np.median(wall)), float(np.median(cpu))


def run(repeats: int) -> tuple[list[dict], dict]:
    left0 = cv2.imread(str(SCENE / "im0.png"))
    right0 = cv2.imread(str(SCENE / "im1.png"))
    if left0 is None or right0 is None:
        raise SystemExit(f"Middlebury scene not found at {SCENE}; set DEPTHRULER_SHARED")
    rows = []
    load_before = os.getloadavg()
    for w, h in SIZES:
        left = cv2.resize(left0, (w, h), interpolation=cv2.INTER_AREA)
        right = cv2.resize(right0, (w, h), interpolation=cv2.INTER_AREA)
        t_bm, c_bm = timed_cpu(lambda: bm_reference(left, right), repeats)
        rows.append({"size": f"{w}x{h}", "config": "StereoBM (reference, bs 15)", "s": t_bm, "cpu": c_bm,
                     "ratio": 1.0})
        for mode in MODES:
            for wls in (False, True):
                cfg = SGBMConfig(num_disparities=64, block_size=5, mode=mode, wls=wls)
                t, c = timed_cpu(lambda: compute_disparity(left, right, cfg), repeats)
                t_ref = timed(lambda: bm_reference(left, right), max(1, repeats // 2))
                rows.append({"size": f"{w}x{h}", "config": f"{mode}{' + WLS' if wls else ''}", "s": t, "cpu": c,
                             "ratio": t / t_ref})
        # The whole live path: rectification remap + default SGBM + Frame.
        fx = 0.9 * w
        k = np.array([[fx, 0, w / 2 - 0.5], [0, fx, h / 2 - 0.5], [0, 0, 1]])
        calib = StereoCalibration(image_size=(w, h), K1=k, D1=np.zeros(5), K2=k, D2=np.zeros(5),
                                  R=cv2.Rodrigues(np.array([0.0, 0.005, 0.0]))[0], T=np.array([-0.06, 0, 0]))
        for label, cfg in (("pipeline: rectify + sgbm_3way", SGBMConfig(num_disparities=64)),
                           ("pipeline: rectify + sgbm_3way + LR confidence",
                            replace(SGBMConfig(num_disparities=64), lr_confidence=True))):
            proc = StereoProcessor(calib, cfg)
            t, c = timed_cpu(lambda: proc.process(left, right), repeats)
            t_ref = timed(lambda: bm_reference(left, right), max(1, repeats // 2))
            rows.append({"size": f"{w}x{h}", "config": label, "s": t, "cpu": c, "ratio": t / t_ref})
    env = {
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": cpu_name(),
        "cores": os.cpu_count(),
        "opencv": cv2.__version__,
        "threads": cv2.getNumThreads(),
        "python": platform.python_version(),
        "load_before": load_before,
        "load_after": os.getloadavg(),
        "repeats": repeats,
    }
    return rows, env


def confidence_cost(repeats: int) -> str:
    """The "## SGBM confidence" section: the default live pipeline (rectify + sgbm_3way) with the texture
    confidence on against off, timed alternately in this process (the ratio is the figure; the target is
    at most 20 % lower frame rate)."""
    left0, right0 = cv2.imread(str(SCENE / "im0.png")), cv2.imread(str(SCENE / "im1.png"))
    if left0 is None or right0 is None:
        raise SystemExit(f"Middlebury scene not found at {SCENE}; set DEPTHRULER_SHARED")
    lines = ["## SGBM confidence", "",
             f"`bench/bench_sgbm.py --confidence`, {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}: "
             f"{cpu_name()}, {os.cpu_count()} cores, OpenCV {cv2.__version__}, load average {os.getloadavg()[0]:.1f} "
             f"before. The live pipeline (rectify + sgbm_3way, 64 disparities) with the texture confidence "
             f"(`texture_confidence`, the default) and without; medians of {repeats} alternating runs.", "",
             "| size | ms without | ms with | frame rate with / without |", "|---|---:|---:|---:|"]
    for w, h in SIZES:
        left = cv2.resize(left0, (w, h), interpolation=cv2.INTER_AREA)
        right = cv2.resize(right0, (w, h), interpolation=cv2.INTER_AREA)
        fx = 0.9 * w
        k = np.array([[fx, 0, w / 2 - 0.5], [0, fx, h / 2 - 0.5], [0, 0, 1]])
        calib = StereoCalibration(image_size=(w, h), K1=k, D1=np.zeros(5), K2=k, D2=np.zeros(5),
                                  R=cv2.Rodrigues(np.array([0.0, 0.005, 0.0]))[0], T=np.array([-0.06, 0, 0]))
        on = StereoProcessor(calib, SGBMConfig(num_disparities=64))
        off = StereoProcessor(calib, SGBMConfig(num_disparities=64, texture_confidence=False))
        t_on, t_off = [], []
        for _ in range(repeats):
            t_off.append(timed(lambda: off.process(left, right), 1))
            t_on.append(timed(lambda: on.process(left, right), 1))
        a, b = float(np.median(t_off)), float(np.median(t_on))
        lines.append(f"| {w}x{h} | {a * 1000:.0f} | {b * 1000:.0f} | {a / b:.2f} |")
    return "\n".join(lines) + "\n"


def accuracy() -> list[dict]:
    """Share of non-occluded Middlebury pixels within 1 px of ground truth, per mode and WLS setting
    (all eight shared scenes at their own disparity range): what each speed buys."""
    from device.sources.middlebury import load_scene, scene_sgbm_config

    scenes = [load_scene(p) for p in sorted(default_data_dir().iterdir()) if (p / "im0.png").is_file()]
    rows = []
    for mode in MODES:
        for wls in (False, True):
            shares = []
            for sc in scenes:
                disp, _ = compute_disparity(sc.left, sc.right, scene_sgbm_config(sc, mode=mode, wls=wls))
                m = sc.nonocc_mask
                shares.append(float(np.mean(np.abs(disp[m] - sc.gt_disparity[m]) <= 1.0)))
            rows.append({"config": f"{mode}{' + WLS' if wls else ''}", "mean": float(np.mean(shares)),
                         "min": float(np.min(shares)), "max": float(np.max(shares))})
    return rows


def table(rows: list[dict], env: dict) -> str:
    lb, la = env["load_before"], env["load_after"]
    lines = [
        "## SGBM",
        "",
        f"`bench/bench_sgbm.py`, {env['date']}: {env['cpu']}, {env['cores']} cores, OpenCV {env['opencv']} "
        f"({env['threads']} threads), Python {env['python']}. Median of {env['repeats']} runs after a warm-up; "
        "Middlebury Motorcycle resized to each size, 64 disparities, block 5, P1/P2 = 8/32*3*bs^2; "
        "times include `compute_disparity`'s conversion to float/NaN and its confidence. "
        f"Load average {lb[0]:.1f} before, {la[0]:.1f} after (machine shared with other jobs: absolute fps "
        "are pessimistic; the ratio to StereoBM, timed alongside, is the steadier number; CPU ms is summed "
        "over OpenCV's threads, so one core's worth of CPU per frame bounds an idle single-core rate).",
        "",
        "| size | configuration | ms / frame | fps | CPU ms / frame | x StereoBM time |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['size']} | {r['config']} | {r['s'] * 1000:.0f} | {1 / r['s']:.1f} | "
                     f"{r['cpu'] * 1000:.0f} | {r['ratio']:.1f} |")
    if env.get("accuracy"):
        wls = SGBMConfig()
        lines += [
            "",
            f"Accuracy on the eight shared Middlebury scenes (share of non-occluded pixels within 1 px of ground "
            f"truth; no match counts as a miss; WLS lambda {wls.wls_lambda:g}, sigma {wls.wls_sigma:g}):",
            "",
            "| configuration | mean | worst scene | best scene |",
            "|---|---:|---:|---:|",
        ]
        for r in env["accuracy"]:
            lines.append(f"| {r['config']} | {r['mean']:.3f} | {r['min']:.3f} | {r['max']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--write", action="store_true", help="update bench/RESULTS.md")
    parser.add_argument("--notes", default="", help="text appended under the table (e.g. the chosen defaults)")
    parser.add_argument("--confidence", action="store_true", help="only the texture confidence's cost (its own section)")
    args = parser.parse_args(argv)
    if args.confidence:
        text = confidence_cost(args.repeats)
        print(text)
        if args.write:
            replace_section("## SGBM confidence", text)
        return
    rows, env = run(args.repeats)
    env["accuracy"] = accuracy()
    text = table(rows, env) + (f"\n{args.notes}\n" if args.notes else "")
    print(text)
    if args.write:
        replace_section("## SGBM", text)


if __name__ == "__main__":
    main()
