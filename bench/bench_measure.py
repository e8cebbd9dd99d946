"""Benchmark: robust measurements on realistic clicks and along the full 1280x720 diagonal.

Two workloads: the diagonal (1280 samples, 40 % outliers: one long segment) and realistic clicks
(the simulated rig's stress profile, a person's clicks on posters and a person at 1-7 m: 20-300
samples, :func:`realistic_cases`). Reports median and p99 time of ``measure_distance`` ("robust"
and "paper"), and the same pipeline with scikit-learn doing our FAST-MCD's work
(:func:`sklearn_same_work`: our starts, subsamples, candidates kept and C-steps, through
scikit-learn's own candidate search), timed side by side in the same process on one BLAS thread;
``--baseline REV`` (repeatable) times earlier revisions' cores beside ours. Run:
``python bench/bench_measure.py`` or ``depthruler bench measure``; ``--runs 5 --write`` repeats the
whole run five times (the host's speed drifts from run to run) and records the table in
bench/RESULTS.md.
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
    ``max_iter`` C-steps, then its consistency correction and reweighting (``MinCovDet``). Beyond
    600 points, as ours (measure.mcd, step 2): the starts split over up to five disjoint subsamples
    of 300, the ``n_best`` best of each two C-steps on the merged subsamples, their ``n_best`` best
    on all the data."""
    from sklearn.covariance import MinCovDet
    from sklearn.covariance._robust_covariance import select_candidates

    from measure.mcd import _MAX_GROUPS, _SUBSAMPLE, default_h

    x = np.asarray(points, dtype=np.float64)
    x = x[:, None] if x.ndim == 1 else x
    n, p = x.shape
    h = default_h(n, p, support_fraction) if h is None else h
    if h >= n:
        return sklearn_mcd(points, support_fraction=h / n, seed=seed)
    rng = np.random.RandomState(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if n > 2 * _SUBSAMPLE:
            groups = min(_MAX_GROUPS, n // _SUBSAMPLE)
            perm = rng.permutation(n)[: groups * _SUBSAMPLE].reshape(groups, _SUBSAMPLE)
            sub = [select_candidates(x[g], max(p + 1, int(math.ceil(h * _SUBSAMPLE / n))), n_trials=max(1, n_starts // groups),
                                     select=n_best, n_iter=2, random_state=rng)[:2] for g in perm]
            merged = x[perm.ravel()]
            trials = (np.concatenate([c[0] for c in sub]), np.concatenate([c[1] for c in sub]))
            trials = select_candidates(merged, max(p + 1, int(math.ceil(h * len(merged) / n))), n_trials=trials, select=n_best,
                                       n_iter=2, random_state=rng)[:2]
        else:
            trials = select_candidates(x, h, n_trials=n_starts, select=n_best, n_iter=2, random_state=rng)[:2]
        loc, cov, support, dist = select_candidates(x, h, n_trials=trials, select=1, n_iter=max_iter, random_state=rng)
        m = MinCovDet(support_fraction=h / n, random_state=rng)
        m.raw_location_, m.raw_covariance_, m.raw_support_ = loc[0], cov[0], support[0]
        m.location_, m.support_, m.dist_ = loc[0], support[0], dist[0]
        m.correct_covariance(x)
        m.reweight_covariance(x)
    return _as_result(m, h)


@contextmanager
def sklearn_backend():
    """The pipeline with scikit-learn doing our FAST-MCD's work (:func:`sklearn_same_work`)."""
    with mock.patch("measure.dline.fast_mcd", sklearn_same_work), mock.patch("measure.linefit.fast_mcd", sklearn_same_work):
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


def _time_side_by_side(call, repeats: int, ref_repeats: int, others=()) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """CPU and wall ms per call of ``call`` with our FAST-MCD (``repeats`` calls), under the
    scikit-learn backend (``ref_repeats`` calls) and, for each of ``others`` (k -> k rows of a
    baseline revision's timings of the same call), of that baseline, interleaved in blocks: this host
    has episodes of a few seconds in which everything runs 1.5-2x slower, and interleaving puts every
    side in the same episodes instead of timing all of ours in one. Each row: cpu, wall. The caller
    has run ``call`` once each way already (the warm-up)."""
    mine, ref, bases = [], [], [[] for _ in others]
    per_block = max(1, repeats // ref_repeats)
    while len(mine) < repeats or len(ref) < ref_repeats:
        k = min(per_block, repeats - len(mine))
        mine.extend(_timed(call) for _ in range(k))
        for other, base in zip(others, bases):
            if k:
                base.extend(other(k))
        if len(ref) < ref_repeats:
            with sklearn_backend():
                ref.append(_timed(call))
    return np.array(mine), np.array(ref), [np.array(b).reshape(-1, 2) for b in bases]


def _vs_baselines(row: dict, labels, bases: list[np.ndarray], mine: np.ndarray, same: list[float]) -> None:
    """Per baseline revision (``labels``): its CPU median and p99 (ms), our median's ratio to its
    median and the share of the same distances (``same``)."""
    row["baselines"] = {
        label: {"cpu_median_ms": float(np.median(b[:, 0])), "cpu_p99_ms": float(np.percentile(b[:, 0], 99)),
                "ratio": float(np.median(mine) / np.median(b[:, 0])), "same": share}
        for label, b, share in zip(labels, bases, same) if b.size
    }


def run_realistic(cases, repeats: int = 5, ref_repeats: int = 1, baselines=(), offset: int = 0) -> dict[str, dict[str, float]]:
    """Per method: CPU ms per measurement over ``cases`` (each timed ``repeats`` times, the reference
    ``ref_repeats`` times and, for each :class:`bench.measure_baseline.Baseline` in ``baselines``
    (holding the cases from index ``offset`` on), that revision ``repeats`` times, interleaved), the
    ratios of the medians, the samples per segment and the share of cases where ours and the reference
    give the same distance (to 0.1 mm), and ours and each baseline."""
    from threadpoolctl import threadpool_limits

    from measure import MeasureError, MeasureOptions, measure_distance

    rows: dict[str, dict[str, float]] = {}
    with threadpool_limits(1):
        for method in ("robust", "paper"):
            opts = MeasureOptions(method=method)
            mine, ref, samples, same = [], [], [], []
            base, same_base = [[] for _ in baselines], [[] for _ in baselines]
            for i, (frame, p1, p2) in enumerate(cases):
                call = lambda: measure_distance(frame, p1, p2, opts)  # noqa: E731
                try:
                    m = call()
                    with sklearn_backend():
                        r = call()
                except MeasureError:
                    continue
                for b, s in zip(baselines, same_base):
                    s.append(abs(m.distance_m - b.time(offset + i, method, 0)[1]) <= 1e-4)
                others = [lambda k, b=b: b.time(offset + i, method, k)[0] for b in baselines]
                a, c, theirs = _time_side_by_side(call, repeats, ref_repeats, others)
                mine.extend(a[:, 0])
                ref.extend(c[:, 0])
                for acc, rows_b in zip(base, theirs):
                    acc.extend(rows_b)
                samples.append(m.n_samples)
                same.append(abs(m.distance_m - r.distance_m) <= 1e-4)
            rows[method] = {
                "cases": len(samples), "samples_median": float(np.median(samples)),
                "samples_range": (int(min(samples)), int(max(samples))),
                "cpu_median_ms": float(np.median(mine)), "cpu_p99_ms": float(np.percentile(mine, 99)),
                "sklearn_cpu_median_ms": float(np.median(ref)), "speedup": float(np.median(ref) / np.median(mine)),
                "same_answer": float(np.mean(same)),
            }
            _vs_baselines(rows[method], [b.label for b in baselines], [np.array(b).reshape(-1, 2) for b in base], np.array(mine),
                          [float(np.mean(s)) for s in same_base])
    return rows


def run(repeats: int = 200, ref_repeats: int = 20, baselines=()) -> dict[str, dict[str, float]]:
    """The diagonal: per method our and the scikit-learn reference's times (and, for each
    :class:`bench.measure_baseline.Baseline` in ``baselines`` holding the diagonal as case 0, that
    revision's)."""
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
            others = [lambda k, b=b: b.time(0, method, k)[0] for b in baselines]
            same = [float(abs(m.distance_m - b.time(0, method, 0)[1]) <= 1e-4) for b in baselines]
            mine, ref, bases = _time_side_by_side(call, repeats, ref_repeats, others)
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
            _vs_baselines(rows[method], [b.label for b in baselines], bases, ours_cpu, same)
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
    "| run | workload | method | baseline | CPU median / p99 ms | baseline CPU median / p99 ms | ratio to baseline | same distance |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- |"
)


def _baseline_row(run_no: int, workload: str, method: str, label: str, r: dict) -> str:
    b = r["baselines"][label]
    return (f"| {run_no} | {workload} | {method} | {label} | {r['cpu_median_ms']:.2f} / {r['cpu_p99_ms']:.2f} | "
            f"{b['cpu_median_ms']:.2f} / {b['cpu_p99_ms']:.2f} | {b['ratio']:.2f} | {100 * b['same']:.0f} % |")


def _baseline_lines(runs: list[dict], realistic: list[dict]) -> list[str]:
    """The table of ours against each baseline revision the runs timed, and per revision the range
    of the robust ratios."""
    pairs = [(i + 1, "diagonal", rows) for i, rows in enumerate(runs)] + [(i + 1, "realistic clicks", rows) for i, rows in enumerate(realistic)]
    labels = list(dict.fromkeys(label for _, _, rows in pairs for r in rows.values() for label in r.get("baselines", {})))
    if not labels:
        return []
    table = [_baseline_row(n, w, m, label, r) for label in labels for w in ("diagonal", "realistic clicks")
             for n, ww, rows in pairs if ww == w for m, r in rows.items() if label in r.get("baselines", {})]
    summary = []
    for label in labels:
        ratios = {w: [r["baselines"][label]["ratio"] for _, ww, rows in pairs if ww == w for m, r in rows.items()
                      if m == "robust" and label in r.get("baselines", {})] for w in ("realistic clicks", "diagonal")}
        summary.append(f"{label}: " + ", ".join(f"{w} {min(v):.2f}-{max(v):.2f}" for w, v in ratios.items() if v))
    return [
        "",
        "Against baseline revisions (each one's measurement core from `git archive` in a child process, the",
        "same frames and clicks, each block of our calls followed by as many of each revision's, CPU time in",
        "each process, one BLAS thread; `--baseline REV`, repeatable):",
        "",
        BASELINE_HEADER,
        *table,
        "",
        "Robust, our median over the baseline's: " + "; ".join(summary) + ".",
    ]


def report(runs: list[dict[str, dict[str, float]]], load: tuple[float, float], date: str,
           realistic: list[dict[str, dict]] = ()) -> str:
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
        "CPU time of this process. The reference is the same pipeline with scikit-learn doing our FAST-MCD's",
        "work in place of `measure.mcd.fast_mcd` (`sklearn_same_work`: our starts over the same nested",
        "subsamples, candidates kept and C-steps, through its `select_candidates`, then its correction and",
        "reweighting; 20 calls), interleaved with ours (10 of ours, 1 reference, and again), so both see the",
        "same slow episodes of this shared host.",
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
            "candidates kept, 2 full-data C-steps); it finds no exact fits, so on quantized segments some",
            "answers differ.",
            "",
            REALISTIC_HEADER,
            *(_realistic_row(i + 1, method, r) for i, rows in enumerate(realistic) for method, r in rows.items()),
            "",
            f"Robust against scikit-learn doing the same work: {min(real):.1f}-{max(real):.1f}x on realistic clicks, "
            f"{min(speedups):.0f}-{max(speedups):.0f}x on the diagonal.",
        ]
    lines += _baseline_lines(runs, list(realistic))
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="repeat the whole benchmark this many times (default 1)")
    ap.add_argument("--repeats", type=int, default=200, help="timed calls of our pipeline per run (default 200)")
    ap.add_argument("--cases", type=int, default=48, help="realistic click cases (default 48)")
    ap.add_argument("--write", action="store_true", help=f"record the table in bench/RESULTS.md ({SECTION!r})")
    ap.add_argument("--baseline", action="append", help=f"revision to time side by side, repeatable (default {BASELINE}); '' for none")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.repeats < 1 or args.cases < 1:
        ap.error("--runs, --repeats and --cases must be at least 1")
    load_before = os.getloadavg()[0]
    runs, realistic = [], []
    cases = realistic_cases(args.cases)
    print(HEADER)
    revisions = [r for r in (args.baseline or [BASELINE]) if r]
    with ExitStack() as stack:
        baselines = []
        if revisions:
            from bench.measure_baseline import Baseline

            for rev in revisions:
                baselines.append(stack.enter_context(Baseline(rev)))
                baselines[-1].load([(diagonal_frame(), (0.0, 0.0), (W - 1.0, H - 1.0))] + cases)
        for i in range(args.runs):
            rows = run(repeats=args.repeats, baselines=baselines)
            runs.append(rows)
            for method, r in rows.items():
                print(_row(i + 1, method, r), flush=True)
            realistic.append(run_realistic(cases, baselines=baselines, offset=1))
            for method, r in realistic[-1].items():
                print(_realistic_row(i + 1, method, r), flush=True)
    text = report(runs, (load_before, os.getloadavg()[0]), datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), realistic)
    print(text.split("\n\n")[-1].strip())
    if args.write:
        replace_section(SECTION, text)
        print(f"recorded in bench/RESULTS.md ({SECTION})")


if __name__ == "__main__":
    main()
