"""Benchmark: one robust measurement along the full 1280x720 diagonal (1280 samples, 40 % outliers).

Reports median and p99 wall time of ``measure_distance`` ("robust" and "paper"), and the same
pipeline with scikit-learn's ``MinCovDet`` in place of our FAST-MCD, timed side by side in
the same process on one BLAS thread. Run: ``python bench/bench_measure.py`` or
``depthruler bench measure``.
"""

from __future__ import annotations

import platform
import time
import warnings
from contextlib import contextmanager
from unittest import mock

import numpy as np

W, H, FX, BASELINE = 1280, 720, 1000.0, 0.08


def diagonal_frame(seed: int = 0, outliers: float = 0.4):
    """A tilted plane filling the view, 1/4-px disparity, ``outliers`` of the pixels wrong."""
    from measure import Frame, PinholeCamera

    rng = np.random.default_rng(seed)
    cam = PinholeCamera(FX, FX, (W - 1) / 2, (H - 1) / 2, W, H)
    xs, ys = np.meshgrid((np.arange(W) - cam.cx) / FX, (np.arange(H) - cam.cy) / FX)
    z = 3.0 / (0.25 * xs - 0.1 * ys + 1.0)
    d = FX * BASELINE / z + rng.normal(0, 0.15, z.shape)
    bad = rng.random(z.shape) < outliers
    d = np.where(bad, d * rng.uniform(0.5, 1.5, z.shape), d)
    d = np.round(d * 4) / 4
    return Frame(np.zeros((H, W, 3), np.uint8), d.astype(np.float32), cam, BASELINE)


def sklearn_mcd(points, *, support_fraction=None, seed=0, **_):
    """The same MCD through scikit-learn (no exact-fit reporting), as an McdResult."""
    from sklearn.covariance import MinCovDet

    from measure.mcd import McdResult, default_h

    x = np.asarray(points, dtype=np.float64)
    x = x[:, None] if x.ndim == 1 else x
    n, p = x.shape
    h = default_h(n, p, support_fraction)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = MinCovDet(support_fraction=h / n, random_state=seed).fit(x)
    return McdResult(
        m.location_, m.covariance_, m.raw_location_, m.raw_covariance_, m.support_, m.raw_support_,
        m.dist_, h, False, "none", None, None, None, 0, float(np.sqrt(np.trace(m.covariance_))),
    )


@contextmanager
def sklearn_backend():
    with mock.patch("measure.dline.fast_mcd", sklearn_mcd), mock.patch("measure.linefit.fast_mcd", sklearn_mcd):
        yield


def _time(fn, repeats: int) -> tuple[np.ndarray, np.ndarray]:
    """Wall and CPU (this process) milliseconds per call. On a shared machine the CPU time is
    what one core spends; the wall time includes waiting for a core."""
    fn()  # warm up
    wall, cpu = np.empty(repeats), np.empty(repeats)
    for i in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        cpu[i] = time.process_time() - c0
        wall[i] = time.perf_counter() - t0
    return wall * 1e3, cpu * 1e3


def run(repeats: int = 200, ref_repeats: int = 20) -> dict[str, dict[str, float]]:
    from threadpoolctl import threadpool_limits

    from measure import MeasureOptions, measure_distance

    frame = diagonal_frame()
    p1, p2 = (0.0, 0.0), (W - 1.0, H - 1.0)
    rows: dict[str, dict[str, float]] = {}
    with threadpool_limits(1):
        for method in ("robust", "paper"):
            opts = MeasureOptions(method=method)
            m = measure_distance(frame, p1, p2, opts)
            ours, ours_cpu = _time(lambda: measure_distance(frame, p1, p2, opts), repeats)
            with sklearn_backend():
                ref_m = measure_distance(frame, p1, p2, opts)
                ref, ref_cpu = _time(lambda: measure_distance(frame, p1, p2, opts), ref_repeats)
            rows[method] = {
                "n_samples": m.n_samples,
                "n_support": m.n_support,
                "median_ms": float(np.median(ours)),
                "p99_ms": float(np.percentile(ours, 99)),
                "cpu_median_ms": float(np.median(ours_cpu)),
                "cpu_p99_ms": float(np.percentile(ours_cpu, 99)),
                "sklearn_median_ms": float(np.median(ref)),
                "sklearn_cpu_median_ms": float(np.median(ref_cpu)),
                "speedup": float(np.median(ref_cpu) / np.median(ours_cpu)),
                "distance_m": m.distance_m,
                "sklearn_distance_m": ref_m.distance_m,
            }
    return rows


def main() -> None:
    rows = run()
    print(f"measure_distance along the 1280x720 diagonal, 40 % outliers; {platform.processor() or platform.machine()}, 1 BLAS thread")
    print("| method | samples | support | CPU median / p99 ms | wall median / p99 ms | sklearn-MCD CPU / wall median ms | speed-up (CPU) | distance m (ours / sklearn) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for method, r in rows.items():
        print(
            f"| {method} | {r['n_samples']} | {r['n_support']} | {r['cpu_median_ms']:.2f} / {r['cpu_p99_ms']:.2f} | "
            f"{r['median_ms']:.2f} / {r['p99_ms']:.2f} | {r['sklearn_cpu_median_ms']:.0f} / {r['sklearn_median_ms']:.0f} | "
            f"{r['speedup']:.0f}x | {r['distance_m']:.4f} / {r['sklearn_distance_m']:.4f} |"
        )


if __name__ == "__main__":
    main()
