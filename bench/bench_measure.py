"""Benchmark: robust measurements on realistic clicks and along the full 1280x720 diagonal.

Two workloads: the diagonal (1280 samples, 40 % outliers: one long segment) and realistic clicks
(the simulated rig's stress profile, a person's clicks on posters and a person at 1-7 m: 20-300
samples, :func:`realistic_cases`). Reports median and p99 time of ``measure_distance`` ("robust"
and "paper"), and the same pipeline with scikit-learn's ``MinCovDet`` in place of our FAST-MCD,
timed side by side in the same process on one BLAS thread. On realistic clicks the reference does
the same work as ours (:func:`sklearn_same_work`: our starts, candidates kept and C-steps, through
scikit-learn's own candidate search); on the diagonal scikit-learn runs its default subset merging. Run: ``python bench/bench_measure.py`` or
``depthruler bench measure``; ``--runs 5 --write`` repeats the whole run five times (the host's
speed drifts from run to run) and records the table in bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from datetime import datetime, timezone
import warnings
from contextlib import ExitStack, contextmanager
from unittest import mock

import numpy as np
from bench.results_file import machine, replace_section

W, H, FX, BASELINE_M = 1280, 720, 1000.0, 0.08
# The core before the speed work of December 2026: `--baseline` times it side by side with this code.
BASELINE = "123ba59"


def diagonal_frame(seed: int = 0, outliers: float = 0.4):
    """A tilted plane filling the view, 1/4-px disparity, ``outliers`` of the pixels wrong."""
    from measure import Frame, PinholeCamera

    rng = np.random.default_rng(seed)
    cam = PinholeCamera(FX, FX, (W - 1) / 2, (H - 1) / 2, W, H)
    xs, ys = np.meshgrid((np.arange(W) - cam.cx) / FX, (np.arange(H) - cam.cy) / FX)
    z = 3.0 / (0.25 * xs - 0.1 * ys + 1.0)
    d = FX * BASELINE_M / z + rng.normal(0, 0.15, z.shape)
    bad = rng.random(z.shape) < outliers
    d = np.where(bad, d * rng.uniform(0.5, 1.5, z.shape), d)
    d = np.round(d * 4) / 4
    return Frame(np.zeros((H, W, 3), np.uint8), d.astype(np.float32), cam, BASELINE_M)


def _as_result(m, h: int):
    """A fitted scikit-learn ``MinCovDet`` as our McdResult (no exact fit: scikit-learn reports none)."""
    from measure.mcd import McdResult

    return McdResult(
        m.location_, m.covariance_, m.raw_location_, m.raw_covariance_, m.support_, m.raw_support_,
        m.dist_, h, False, "none", None, None, None, 0, float(np.sqrt(np.trace(m.covariance_))),
    )


def sklearn_mcd(points, *, support_fraction=None, seed=0, **_):
    """The same MCD through scikit-learn (no exact-fit reporting), as an McdResult."""
    from sklearn.covariance import MinCovDet

    from measure.mcd import default_h

    x = np.asarray(points, dtype=np.float64)
    x = x[:, None] if x.ndim == 1 else x
    n, p = x.shape
    h = default_h(n, p, support_fraction)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = MinCovDet(support_fraction=h / n, random_state=seed).fit(x)
    return _as_result(m, h)


def sklearn_same_work(points, *, support_fraction=None, h=None, n_starts=500, n_best=10, max_iter=100, seed=0, **_):
    """The MCD through scikit-learn doing our FAST-MCD's work: ``n_starts`` random starts of two
    C-steps each (scikit-learn's ``select_candidates``), the ``n_best`` best refined for at most
    ``max_iter`` C-steps, then its consistency correction and reweighting (``MinCovDet``). Used where
    our FAST-MCD runs on all the data at once (n <= 600); beyond, scikit-learn's own :func:`sklearn_mcd`."""
    from sklearn.covariance import MinCovDet
    from sklearn.covariance._robust_covariance import select_candidates

    from measure.mcd import _SUBSAMPLE, default_h

    x = np.asarray(points, dtype=np.float64)
    x = x[:, None] if x.ndim == 1 else x
    n, p = x.shape
    h = default_h(n, p, support_fraction) if h is None else h
    if n > 2 * _SUBSAMPLE or h >= n:
        return sklearn_mcd(points, support_fraction=h / n, seed=seed)
    rng = np.random.RandomState(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        locs, covs, _, _ = select_candidates(x, h, n_trials=n_starts, select=n_best, n_iter=2, random_state=rng)
        loc, cov, support, dist = select_candidates(x, h, n_trials=(locs, covs), select=1, n_iter=max_iter, random_state=rng)
        m = MinCovDet(support_fraction=h / n, random_state=rng)
        m.raw_location_, m.raw_covariance_, m.raw_support_ = loc[0], cov[0], support[0]
        m.location_, m.support_, m.dist_ = loc[0], support[0], dist[0]
        m.correct_covariance(x)
        m.reweight_covariance(x)
    return _as_result(m, h)


@contextmanager
def sklearn_backend(same_work: bool = False):
    mcd = sklearn_same_work if same_work else sklearn_mcd
    with mock.patch("measure.dline.fast_mcd", mcd), mock.patch("measure.linefit.fast_mcd", mcd):
        yield


def realistic_cases(n: int = 48) -> list[tuple[object, tuple[float, float], tuple[float, float]]]:
    """``n`` (frame, click 1, click 2) as people click them on the simulated rig (stress profile, its
    click model): poster widths and lengths and a person's height at 3-7 m (where each is fully in
    view at 1280x720), one seed each."""
    from sim.scenario import scenario

    plan = [("poster", "poster-width"), ("poster", "poster-length"), ("person", "person-height")]
    cases = []
    for i in range(n):
        scene, target = plan[i % len(plan)]
        frame, _, (p1, p2) = scenario(scene, target=target, distance_m=3.0 + (i // len(plan)) % 5, seed=i)
        cases.append((frame, p1, p2))
    return cases


def _timed(fn) -> tuple[float, float]:
    """Wall and CPU (this process) milliseconds of one call. On a shared machine the CPU time is
    what one core spends; the wall time includes waiting for a core."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return (time.process_time() - c0) * 1e3, (time.perf_counter() - t0) * 1e3


def _time_side_by_side(call, repeats: int, ref_repeats: int, same_work: bool = False, other=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CPU and wall ms per call of ``call`` with our FAST-MCD (``repeats`` calls), under the
    scikit-learn backend (``ref_repeats`` calls) and, given ``other`` (k -> k rows of the baseline
    revision's timings of the same call), of the baseline, interleaved in blocks: this host has
    episodes of a few seconds in which everything runs 1.5-2x slower, and interleaving puts every
    side in the same episodes instead of timing all of ours in one. Each row: cpu, wall. The caller
    has run ``call`` once each way already (the warm-up)."""
    mine, ref, base = [], [], []
    per_block = max(1, repeats // ref_repeats)
    while len(mine) < repeats or len(ref) < ref_repeats:
        k = min(per_block, repeats - len(mine))
        mine.extend(_timed(call) for _ in range(k))
        if other is not None and k:
            base.extend(other(k))
        if len(ref) < ref_repeats:
            with sklearn_backend(same_work):
                ref.append(_timed(call))
    return np.array(mine), np.array(ref), np.array(base).reshape(-1, 2)


def _vs_baseline(row: dict, base: np.ndarray, mine: np.ndarray) -> None:
    """The baseline revision's CPU median and p99 (ms) and our median's ratio to its median."""
    row["baseline_cpu_median_ms"] = float(np.median(base[:, 0]))
    row["baseline_cpu_p99_ms"] = float(np.percentile(base[:, 0], 99))
    row["vs_baseline"] = float(np.median(mine) / np.median(base[:, 0]))


def run_realistic(cases, repeats: int = 5, ref_repeats: int = 1, baseline=None, offset: int = 0) -> dict[str, dict[str, float]]:
    """Per method: CPU ms per measurement over ``cases`` (each timed ``repeats`` times, the reference
    ``ref_repeats`` times and, given a :class:`bench.measure_baseline.Baseline` holding the cases from
    index ``offset`` on, the baseline revision ``repeats`` times, interleaved), the ratios of the
    medians, the samples per segment and the share of cases where ours and the reference give the
    same distance (to 0.1 mm), and ours and the baseline."""
    from threadpoolctl import threadpool_limits

    from measure import MeasureError, MeasureOptions, measure_distance

    rows: dict[str, dict[str, float]] = {}
    with threadpool_limits(1):
        for method in ("robust", "paper"):
            opts = MeasureOptions(method=method)
            mine, ref, base, samples, same, same_base = [], [], [], [], [], []
            for i, (frame, p1, p2) in enumerate(cases):
                call = lambda: measure_distance(frame, p1, p2, opts)  # noqa: E731
                try:
                    m = call()
                    with sklearn_backend(True):
                        r = call()
                except MeasureError:
                    continue
                other = None
                if baseline is not None:
                    same_base.append(abs(m.distance_m - baseline.time(offset + i, method, 0)[1]) <= 1e-4)
                    other = lambda k: baseline.time(offset + i, method, k)[0]  # noqa: E731
                a, b, c = _time_side_by_side(call, repeats, ref_repeats, same_work=True, other=other)
                mine.extend(a[:, 0])
                ref.extend(b[:, 0])
                base.extend(c)
                samples.append(m.n_samples)
                same.append(abs(m.distance_m - r.distance_m) <= 1e-4)
            rows[method] = {
                "cases": len(samples), "samples_median": float(np.median(samples)),
                "samples_range": (int(min(samples)), int(max(samples))),
                "cpu_median_ms": float(np.median(mine)), "cpu_p99_ms": float(np.percentile(mine, 99)),
                "sklearn_cpu_median_ms": float(np.median(ref)), "speedup": float(np.median(ref) / np.median(mine)),
                "same_answer": float(np.mean(same)),
            }
            if base:
                _vs_baseline(rows[method], np.array(base), np.array(mine))
                rows[method]["same_as_baseline"] = float(np.mean(same_base))
    return rows


def run(repeats: int = 200, ref_repeats: int = 20, baseline=None) -> dict[str, dict[str, float]]:
    """The diagonal: per method our and the scikit-learn reference's times (and, given a
    :class:`bench.measure_baseline.Baseline` holding the diagonal as case 0, the baseline revision's)."""
    from threadpoolctl import threadpool_limits

    from measure import MeasureOptions, measure_distance

    frame = diagonal_frame()
    p1, p2 = (0.0, 0.0), (W - 1.0, H - 1.0)
    rows: dict[str, dict[str, float]] = {}
    with threadpool_limits(1):
        for method in ("robust", "paper"):
            opts = MeasureOptions(method=method)
            call = lambda: measure_distance(frame, p1, p2, opts)  # noqa: E731
            m = call()  # these two answers are also the warm-up
            with sklearn_backend():
                ref_m = call()
            other = None if baseline is None else (lambda k: baseline.time(0, method, k)[0])  # noqa: E731
            base_m = math.nan if baseline is None else baseline.time(0, method, 0)[1]
            mine, ref, base = _time_side_by_side(call, repeats, ref_repeats, other=other)
            (ours_cpu, ours), (ref_cpu, ref) = mine.T, ref.T
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
            if base.size:
                _vs_baseline(rows[method], base, ours_cpu)
                rows[method]["same_as_baseline"] = float(abs(m.distance_m - base_m) <= 1e-4)
    return rows


SECTION = "## Measurement core: speed"
TARGET_MS, TARGET_SPEEDUP = 5.0, 100.0
HEADER = (
    "| run | method | samples | support | CPU median / p99 ms | wall median / p99 ms | "
    "sklearn-MCD CPU / wall median ms | speed-up (CPU) | distance m (ours / sklearn) |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
)


def _row(run_no: int, method: str, r: dict[str, float]) -> str:
    return (
        f"| {run_no} | {method} | {r['n_samples']} | {r['n_support']} | {r['cpu_median_ms']:.2f} / {r['cpu_p99_ms']:.2f} | "
        f"{r['median_ms']:.2f} / {r['p99_ms']:.2f} | {r['sklearn_cpu_median_ms']:.0f} / {r['sklearn_median_ms']:.0f} | "
        f"{r['speedup']:.0f}x | {r['distance_m']:.4f} / {r['sklearn_distance_m']:.4f} |"
    )


REALISTIC_HEADER = (
    "| run | method | cases | samples median (range) | CPU median / p99 ms | sklearn same work CPU median ms | "
    "speed-up (CPU) | same distance |\n| --- | --- | --- | --- | --- | --- | --- | --- |"
)


def _realistic_row(run_no: int, method: str, r: dict) -> str:
    lo, hi = r["samples_range"]
    return (f"| {run_no} | {method} | {r['cases']} | {r['samples_median']:.0f} ({lo}-{hi}) | {r['cpu_median_ms']:.2f} / "
            f"{r['cpu_p99_ms']:.2f} | {r['sklearn_cpu_median_ms']:.1f} | {r['speedup']:.1f}x | {100 * r['same_answer']:.0f} % |")


BASELINE_HEADER = (
    "| run | workload | method | CPU median / p99 ms | baseline CPU median / p99 ms | ratio to baseline | same distance |\n"
    "| --- | --- | --- | --- | --- | --- | --- |"
)


def _baseline_row(run_no: int, workload: str, method: str, r: dict) -> str:
    return (f"| {run_no} | {workload} | {method} | {r['cpu_median_ms']:.2f} / {r['cpu_p99_ms']:.2f} | "
            f"{r['baseline_cpu_median_ms']:.2f} / {r['baseline_cpu_p99_ms']:.2f} | {r['vs_baseline']:.2f} | {100 * r['same_as_baseline']:.0f} % |")


def _baseline_lines(runs: list[dict], realistic: list[dict], baseline: str) -> list[str]:
    """The table of ours against the baseline revision, when the runs timed one."""
    pairs = [(i + 1, "diagonal", rows) for i, rows in enumerate(runs)] + [(i + 1, "realistic clicks", rows) for i, rows in enumerate(realistic)]
    table = sorted((_baseline_row(n, w, m, r), n, w) for n, w, rows in pairs for m, r in rows.items() if "vs_baseline" in r)
    if not table:
        return []
    ratios = {w: [r["vs_baseline"] for n, ww, rows in pairs if ww == w for m, r in rows.items() if m == "robust" and "vs_baseline" in r]
              for w in ("realistic clicks", "diagonal")}
    return [
        "",
        f"Against the baseline revision {baseline} (its measurement core from `git archive` in a child process, the",
        "same frames and clicks, each block of our calls followed by as many of its, CPU time in each process,",
        "one BLAS thread; `--baseline REV`):",
        "",
        BASELINE_HEADER,
        *(row for row, _, _ in sorted(table, key=lambda x: (x[1], x[2]))),
        "",
        "Robust, our median over the baseline's: " + "; ".join(f"{w} {min(v):.2f}-{max(v):.2f}" for w, v in ratios.items() if v) + ".",
    ]


def report(runs: list[dict[str, dict[str, float]]], load: tuple[float, float], date: str,
           realistic: list[dict[str, dict]] = (), baseline: str = "") -> str:
    """The RESULTS.md section: every run's rows, the machine, and whether the targets hold."""
    from threadpoolctl import threadpool_info

    blas = ", ".join(sorted({f"{i.get('internal_api', '?')} {i.get('version', '?')}" for i in threadpool_info()}))
    robust = [r["robust"] for r in runs]
    medians = [r["cpu_median_ms"] for r in robust]
    speedups = [r["speedup"] for r in robust]
    met = sum(m <= TARGET_MS and s >= TARGET_SPEEDUP for m, s in zip(medians, speedups))
    lines = [
        SECTION,
        "",
        "`bench/bench_measure.py` (`depthruler bench measure --runs N --write`): one measurement along the",
        "full 1280x720 diagonal (1280 samples; 40 % of the pixels wrong by 0.5-1.5x, 1/4-px quantization,",
        "a tilted plane at about 3 m), 200 timed calls after a warm-up, one BLAS thread (`threadpoolctl`),",
        "CPU time of this process. The reference is the same pipeline with scikit-learn's `MinCovDet` in",
        "place of `measure.mcd.fast_mcd` (20 calls), interleaved with ours (10 of ours, 1 reference, and",
        "again), so both see the same slow episodes of this shared host; both give the same distance.",
        f"Target: robust median <= {TARGET_MS:g} ms and >= {TARGET_SPEEDUP:g}x.",
        "",
        HEADER,
        *(_row(i + 1, method, r) for i, rows in enumerate(runs) for method, r in rows.items()),
        "",
        f"Machine: {machine()}, numpy {np.__version__}, {blas}; {date}; 1-minute load average "
        f"{load[0]:.2f} before, {load[1]:.2f} after.",
        "",
        f"Robust: CPU median {min(medians):.2f}-{max(medians):.2f} ms, speed-up {min(speedups):.0f}-{max(speedups):.0f}x; "
        f"both targets met in {met} of {len(runs)} runs.",
    ]
    if realistic:
        real = [r["robust"]["speedup"] for r in realistic]
        lines += [
            "",
            "Realistic clicks (`realistic_cases`: a person's clicks on poster widths and lengths and a person's",
            "height at 3-7 m on the simulated rig's stress profile, one seed each), each timed 5 times against",
            "1 reference call, interleaved. The reference does the same work as ours (our 104 starts, 5",
            "candidates kept, 2 full-data C-steps, through scikit-learn's `select_candidates`, then its",
            "correction and reweighting); it finds no exact fits, so on quantized segments some answers differ.",
            "",
            REALISTIC_HEADER,
            *(_realistic_row(i + 1, method, r) for i, rows in enumerate(realistic) for method, r in rows.items()),
            "",
            f"Robust against scikit-learn doing the same work: {min(real):.1f}-{max(real):.1f}x on realistic clicks, "
            f"{min(speedups):.0f}-{max(speedups):.0f}x on the diagonal (where scikit-learn switches to its "
            "subset merging at its own settings).",
        ]
    lines += _baseline_lines(runs, list(realistic), baseline)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="repeat the whole benchmark this many times (default 1)")
    ap.add_argument("--repeats", type=int, default=200, help="timed calls of our pipeline per run (default 200)")
    ap.add_argument("--cases", type=int, default=48, help="realistic click cases (default 48)")
    ap.add_argument("--write", action="store_true", help=f"record the table in bench/RESULTS.md ({SECTION!r})")
    ap.add_argument("--baseline", default=BASELINE, help=f"revision to time side by side (default {BASELINE}); '' for none")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.repeats < 1 or args.cases < 1:
        ap.error("--runs, --repeats and --cases must be at least 1")
    load_before = os.getloadavg()[0]
    runs, realistic = [], []
    cases = realistic_cases(args.cases)
    print(HEADER)
    with ExitStack() as stack:
        base = None
        if args.baseline:
            from bench.measure_baseline import Baseline

            base = stack.enter_context(Baseline(args.baseline))
            base.load([(diagonal_frame(), (0.0, 0.0), (W - 1.0, H - 1.0))] + cases)
        for i in range(args.runs):
            rows = run(repeats=args.repeats, baseline=base)
            runs.append(rows)
            for method, r in rows.items():
                print(_row(i + 1, method, r), flush=True)
            realistic.append(run_realistic(cases, baseline=base, offset=1))
            for method, r in realistic[-1].items():
                print(_realistic_row(i + 1, method, r), flush=True)
    label = f"{args.baseline} ({base.short})" if base is not None else ""
    text = report(runs, (load_before, os.getloadavg()[0]), datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), realistic, label)
    print(text.split("\n\n")[-1].strip())
    if args.write:
        replace_section(SECTION, text)
        print(f"recorded in bench/RESULTS.md ({SECTION})")


if __name__ == "__main__":
    main()
