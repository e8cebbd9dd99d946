"""Fuzzing the measurement core: random frames, cameras, clicks and options.

Every case either raises MeasureError with a message or returns a finite, sane Measurement;
never another exception, a hang or a warning. Frames: 8-200 px, all-NaN, holes, constant,
quantized, tilted planes with outliers, and maps drawn from {0, 1e-30, 1e30, +-inf, 3.0, NaN};
focal lengths and baselines at and beyond their physical ranges; clicks in and around the image.
"""

from __future__ import annotations

import math
import re

import numpy as np
from hypothesis import event, given
from hypothesis import strategies as st

from fuzzing import EDGE_FLOATS, finite, no_warnings, typed_or_answer
from measure import Frame, MeasureError, MeasureOptions, Measurement, PinholeCamera, measure_distance
from measure.mcd import fast_mcd
from measure.types import METHODS
from measure.zonly import measure_z_only

PALETTE = np.array([0.0, 1e-30, 1e30, np.inf, -np.inf, 3.0, np.nan])
MAP_KINDS = ("plane", "palette", "quantized-plane", "holes", "constant", "all-nan", "plane", "quantized-plane")


@st.composite
def disparity_maps(draw: st.DrawFn, w: int, h: int) -> np.ndarray:
    """A float32 h x w disparity map of one of MAP_KINDS; bulk pixels from a drawn numpy seed."""
    kind = draw(st.sampled_from(MAP_KINDS))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if kind == "palette":
        weights = np.array(draw(st.lists(st.floats(0.0, 1.0), min_size=len(PALETTE), max_size=len(PALETTE))))
        weights = weights / weights.sum() if weights.sum() > 0 else None
        d = rng.choice(PALETTE, size=(h, w), p=weights)
    elif kind == "constant":
        d = np.full((h, w), draw(st.one_of(st.sampled_from(list(PALETTE)), EDGE_FLOATS)))
    elif kind == "all-nan":
        d = np.full((h, w), np.nan)
    else:
        a = draw(st.one_of(st.floats(0.5, w / 2), st.floats(0.5, w / 2), st.floats(-50.0, 300.0)))
        slope = st.one_of(st.just(0.0), st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-2.0, 2.0))
        bx, by = draw(slope), draw(slope)
        ys, xs = np.mgrid[0:h, 0:w]
        d = a + bx * xs + by * ys + rng.normal(0.0, draw(st.sampled_from([0.0, 0.05, 0.5, 5.0])), (h, w))
        if kind == "quantized-plane":
            q = draw(st.sampled_from([1 / 32, 0.25, 1.0, 8.0, 64.0]))
            d = np.round(d / q) * q
        outliers = rng.random((h, w)) < draw(st.one_of(st.just(0.0), st.floats(0.0, 0.5), st.floats(0.0, 0.9)))
        d[outliers] = rng.choice(PALETTE, size=int(outliers.sum())) if draw(st.booleans()) else rng.uniform(-5, 400, int(outliers.sum()))
    if kind == "holes" or draw(st.booleans()):
        d[rng.random((h, w)) < draw(st.one_of(st.floats(0.0, 0.5), st.floats(0.0, 1.0), st.just(0.9)))] = np.nan
    with np.errstate(over="ignore"):  # 1e300 -> inf in float32 is part of the fuzz
        return d.astype(np.float32)


def in_range(lo: float, hi: float, typical: float) -> st.SearchStrategy[float]:
    """Numbers in a physical range, its two ends included."""
    return st.one_of(st.sampled_from([lo, hi, min(max(typical, lo), hi)]), st.floats(lo, hi))


OUT_OF_RANGE = st.one_of(EDGE_FLOATS, st.sampled_from([1e-6, 1e9, 1e-9, 1e6, 0.0, -500.0, None, "500", True]))


@st.composite
def clicks(draw: st.DrawFn, w: int, h: int) -> object:
    """Mostly inside the image; sometimes around it, on its corners, or not a point at all."""
    kind = draw(st.integers(0, 9))
    if kind <= 6:
        return (draw(st.floats(0, w - 1)), draw(st.floats(0, h - 1)))
    if kind == 7:
        return (draw(st.floats(-w, 2 * w)), draw(st.floats(-h, 2 * h)))
    if kind == 8:
        return draw(st.sampled_from([(0.0, 0.0), (w - 1.0, h - 1.0), (w - 1.0, 0.0), (0.0, h - 1.0), (w - 0.5, h / 2)]))
    return draw(st.one_of(st.tuples(EDGE_FLOATS, EDGE_FLOATS), st.sampled_from([(1.0,), "1,2", None, (1, 2, 3), [[1, 2]]])))


VALID_OPTIONS = {
    "method": st.sampled_from(METHODS),
    "support_fraction": in_range(0.5, 1.0, 0.75),
    "window": st.sampled_from([1, 3, 5, 7, 9, 51]),
    "extension_px": st.one_of(st.sampled_from([3, 25, 500]), st.integers(3, 300)),
    "gap_detection": st.booleans(),
    "seed": st.one_of(st.integers(0, 10), st.integers(0, 2**32 - 1)),
    "click_px": st.one_of(st.sampled_from([0, 0.0, 1.5, 3, 50.0]), in_range(0.0, 50.0, 1.5)),
}
BAD_OPTIONS = {
    "method": st.sampled_from(["", "ROBUST", "magic", 3, None]),
    "support_fraction": st.one_of(EDGE_FLOATS.filter(lambda v: not 0.5 <= v <= 1.0), st.sampled_from([0.49, 1.01, "0.5", None])),
    "window": st.one_of(st.integers(-3, 10**9).filter(lambda v: v < 1 or v > 51 or v % 2 == 0),
                        st.sampled_from([53, 201, 5.0, 5.5, True, "5"])),
    "extension_px": st.one_of(st.integers(-3, 2), st.sampled_from([501, 10**9, 25.0, "25", None])),
    "gap_detection": st.sampled_from([0, 1, "yes", None]),
    "seed": st.one_of(st.integers(-5, -1), st.sampled_from([2**32, 2**64, 1.5, "0", None])),
    "click_px": st.one_of(EDGE_FLOATS.filter(lambda v: not 0.0 <= v <= 50.0), st.sampled_from([-1e-9, 50.5, True, "1.5", None])),
}
CORRUPTIBLE = ("fx", "fy", "cx", "cy", "baseline_m", "doffs", *VALID_OPTIONS)


@st.composite
def cases(draw: st.DrawFn) -> tuple:
    """A frame, two clicks and options; half the cases have one number out of range or of the wrong type."""
    w, h = draw(st.integers(8, 200)), draw(st.integers(8, 200))
    size = max(w, h)
    corrupt = draw(st.sampled_from(CORRUPTIBLE)) if draw(st.integers(0, 2)) == 0 else None
    f = draw(in_range(0.05 * size, 1e4 * size, 500.0))
    reach = 1e3 * size
    fields = {
        "fx": f,
        "fy": draw(st.one_of(st.just(f), in_range(0.05 * size, 1e4 * size, f))),
        "cx": draw(st.one_of(st.just((w - 1) / 2), in_range(-reach, w + reach, 0.0))),
        "cy": draw(st.one_of(st.just((h - 1) / 2), in_range(-reach, h + reach, 0.0))),
        "baseline_m": draw(in_range(1e-4, 1e3, 0.07)),
        "doffs": draw(st.one_of(st.just(0.0), st.just(0.0), st.floats(-30.0, 300.0), st.sampled_from([-2001.0 * size, 2001.0 * size]))),
    }
    opts = {k: draw(v) for k, v in VALID_OPTIONS.items() if draw(st.booleans())}
    if corrupt in VALID_OPTIONS:
        opts[corrupt] = draw(BAD_OPTIONS[corrupt])
    elif corrupt is not None:
        fields[corrupt] = draw(OUT_OF_RANGE)
    cam = {k: fields[k] for k in ("fx", "fy", "cx", "cy")} | {"width": w, "height": h}
    disparity = draw(disparity_maps(w, h))
    p1 = draw(clicks(w, h))
    if isinstance(p1, tuple) and len(p1) == 2 and draw(st.integers(0, 5)) == 0:
        # A second click a few pixels away in some direction (maybe off the image).
        r, a = draw(st.floats(0.5, 12.0)), draw(st.floats(0.0, 2 * math.pi))
        p2 = (p1[0] + r * math.cos(a), p1[1] + r * math.sin(a))
    else:
        p2 = draw(clicks(w, h))
        if p2 == p1 and isinstance(p1, tuple) and len(p1) == 2 and draw(st.integers(0, 9)):  # hypothesis likes equal draws; keep a few
            p2 = (w - 1 - p1[0], h - 1 - p1[1])
    return disparity, cam, fields["baseline_m"], fields["doffs"], p1, p2, opts


def _check(m: Measurement) -> None:
    assert isinstance(m, Measurement)
    assert finite(m.distance_m) and m.distance_m >= 0, m
    if hasattr(m, "uncertainty_m"):
        assert finite(m.uncertainty_m) and m.uncertainty_m > 0, m
    assert finite(m.p1_m) and finite(m.p2_m), m
    assert 0 <= m.n_support <= m.n_valid <= max(m.n_samples, 2)
    assert m.to_dict()["distance_m"] == m.distance_m


def _frame(disparity, cam, baseline, doffs) -> Frame | None:
    h, w = disparity.shape

    def build() -> Frame:
        return Frame(np.zeros((h, w, 3), np.uint8), disparity, PinholeCamera(**cam), baseline_m=baseline, doffs=doffs)

    return typed_or_answer(build, MeasureError)


def _run(measure, case) -> None:
    disparity, cam, baseline, doffs, p1, p2, opts = case
    frame = _frame(disparity, cam, baseline, doffs)
    options = typed_or_answer(lambda: MeasureOptions(**opts), MeasureError)
    if frame is None or options is None:
        event("frame or options rejected")
        return
    m = typed_or_answer(lambda: measure(frame, p1, p2, options), MeasureError)
    event(f"{options.method}: {'MeasureError' if m is None else 'answer'}")
    if m is None:
        try:
            measure(frame, p1, p2, options)
        except MeasureError as exc:
            event("MeasureError: " + re.sub(r"[-+(]?[0-9][^ ]*", "#", str(exc))[:36])
    if m is not None:
        _check(m)


@given(cases())
def test_measure_distance_answers_or_raises_measure_error(case):
    _run(measure_distance, case)


@given(cases())
def test_z_only_ablation_answers_or_raises_measure_error(case):
    _run(measure_z_only, case)


def test_the_first_fuzz_findings_answer_or_raise():
    """The first fuzzing run's findings: iteration 11 crashed the paper method; 1e30 overflowed FAST-MCD."""
    rng = np.random.default_rng(1)
    w, h = 19, 167
    answered = beyond = 0
    for _ in range(60):
        d = rng.choice([0, 1e-30, 1e30, np.inf, -np.inf, 3.0], size=(h, w)).astype(np.float32)
        fr = Frame(np.zeros((h, w, 3), np.uint8), d, PinholeCamera(500.0, 500.0, w / 2, h / 2, w, h), baseline_m=0.07)
        for method in METHODS:
            try:
                m = typed_or_answer(lambda: measure_distance(fr, (3.08, 16.49), (15.63, 19.39), MeasureOptions(method=method)), ())
            except MeasureError as exc:
                assert str(exc).strip()
                beyond += "beyond the measurable range" in str(exc)
                continue
            _check(m)
            assert re.search(r"disagree by \d{1,4} %|disagree by more than 1000 %", " ".join(m.reasons)) or "disagree" not in " ".join(m.reasons), m.reasons
            answered += 1
    # The 5x5 windows always hold depth here; a median of 1e-30 px (1e31 m) is not a depth, it is
    # beyond the measurable range (a MeasureError saying so), and so is a robust line through it.
    assert answered >= 30 and beyond >= 30, (answered, beyond)


def test_impossible_disparities_are_holes():
    """1e30 px (wider than the image), +-inf, NaN and d <= -doffs are no samples; 3.0 px is."""
    w, h = 40, 30
    d = np.full((h, w), 3.0, np.float32)
    d[:, ::2] = np.float32(1e30)
    d[::3, :] = np.inf
    fr = Frame(np.zeros((h, w, 3), np.uint8), d, PinholeCamera(50.0, 50.0, 20.0, 15.0, w, h), baseline_m=0.1, doffs=-2.0)
    valid = fr.valid(fr.disparity)
    assert valid.sum() == ((np.arange(h) % 3 != 0)[:, None] & (np.arange(w) % 2 == 1)[None, :]).sum()
    assert np.allclose(fr.depth()[valid], 50.0 * 0.1 / 1.0) and np.isnan(fr.depth()[~valid]).all()
    m = measure_distance(fr, (1.0, 1.0), (35.0, 28.0), MeasureOptions(method="paper", gap_detection=False))
    assert m.n_valid == int(valid[m.samples_px[:, 1], m.samples_px[:, 0]].sum()) == len(m.samples_px)


@given(
    n=st.integers(1, 400),
    p=st.integers(1, 3),
    seed=st.integers(0, 2**32 - 1),
    scales=st.lists(st.sampled_from([0.0, 1e-30, 1e-6, 1.0, 1e6, 1e30, 1e60, 1e99]), min_size=2, max_size=2),
    outliers=st.floats(0.0, 0.6),
    support_fraction=st.one_of(st.none(), st.floats(0.5, 1.0)),
)
def test_fast_mcd_never_warns_on_finite_points(n, p, seed, scales, outliers, support_fraction):
    """Inliers at one scale, outliers at another (up to 1e99 apart): an answer in range, no warning."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 1.0, (n, p)) * scales[0]
    bad = rng.random(n) < outliers
    x[bad] = rng.normal(0.0, 1.0, (int(bad.sum()), p)) * scales[1]
    if rng.random() < 0.3:
        x = np.round(x, 1)  # ties: exact fits
    res = typed_or_answer(lambda: fast_mcd(x, support_fraction=support_fraction, seed=seed), MeasureError)
    assert res is not None  # every coordinate is below 1e100 here
    assert np.isfinite(res.location).all() and np.isfinite(res.covariance).all()
    assert res.support.shape == (n,) and res.support.any()
    assert np.all(np.linalg.eigvalsh(res.covariance) >= -1e-9 * max(1.0, float(np.abs(res.covariance).max())))


@given(st.sampled_from([1e101, 1e300, -1e200]))
def test_fast_mcd_rejects_coordinates_beyond_float_range(big):
    x = np.zeros((10, 2))
    x[3, 1] = big
    assert typed_or_answer(lambda: fast_mcd(x), MeasureError) is None


@given(
    w=st.integers(8, 200), h=st.integers(8, 200),
    field=st.sampled_from(["fx", "fy", "cx", "cy", "width", "height"]),
    value=st.one_of(EDGE_FLOATS, st.sampled_from([None, "500", True, 1e-6, 1e9, 0, -1]), st.integers(-10**12, 10**12)),
)
def test_camera_out_of_range_names_the_field(w, h, field, value):
    kw = dict(fx=100.0, fy=100.0, cx=w / 2, cy=h / 2, width=w, height=h)
    kw[field] = value
    try:
        cam = PinholeCamera(**kw)
    except MeasureError as exc:
        # A new size can put the (unchanged) focal length out of range: that field is named then.
        assert field in str(exc) or (field in ("width", "height") and any(f in str(exc) for f in kw)), str(exc)
        return
    # Accepted: then every number is finite and in its physical range.
    size = max(cam.width, cam.height)
    assert 0.05 * size <= cam.fx <= 1e4 * size and 0.05 * size <= cam.fy <= 1e4 * size
    assert all(math.isfinite(v) for v in (cam.cx, cam.cy))


@given(field=st.sampled_from(["baseline_m", "doffs"]), value=st.one_of(EDGE_FLOATS, st.sampled_from([None, "0.1", True, 1e-9, 1e6])))
def test_frame_numbers_out_of_range_name_the_field(field, value):
    w, h = 16, 12
    kw = dict(image=np.zeros((h, w, 3), np.uint8), disparity=np.ones((h, w), np.float32),
              camera=PinholeCamera(20.0, 20.0, 8.0, 6.0, w, h), baseline_m=0.1, doffs=0.0)
    kw[field] = value
    try:
        Frame(**kw)
    except MeasureError as exc:
        assert field in str(exc), str(exc)


@st.composite
def staircases(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Quantized samples along a segment: a line of any slope with noise, rounded to a quantum, and
    sometimes a few samples on far levels (wrong matches); positions with gaps (holes) and repeats."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    q = draw(st.sampled_from([1 / 16, 0.25, 1.0, 4.0]))
    n = draw(st.integers(3, 400))
    t = np.sort(rng.uniform(0.0, draw(st.sampled_from([2.0, 30.0, 1280.0])), n))
    if draw(st.booleans()):
        t = np.round(t)  # integer pixel positions, repeats possible
    level0 = draw(st.floats(0.5, 200.0)) / q
    rise = draw(st.one_of(st.just(0.0), st.floats(-3.0, 3.0), st.floats(-1.0, 1.0)))  # quanta over the span
    noise = draw(st.sampled_from([0.0, 0.05, 0.15, 0.3, 1.0]))  # in quanta, before rounding
    d = np.round(level0 + rise * (t - t.min()) / max(float(np.ptp(t)), 1.0) + rng.normal(0.0, noise, n)) * q
    wrong = rng.random(n) < draw(st.sampled_from([0.0, 0.0, 0.02, 0.2]))
    d[wrong] += q * rng.choice([-2.0, 2.0, 5.0], size=int(wrong.sum()))
    inflation = draw(st.sampled_from([1.0, 1.7, 6.0]))
    return t, d, q, inflation


@given(staircases())
def test_censored_line_is_finite_and_stays_near_its_levels(case):
    """The interval-censored line (measure/censored.py) on any few-level samples: None, or a finite line
    that at the support's ends stays within two quanta of the levels seen, with a symmetric positive
    semi-definite covariance; never a warning."""
    from measure.censored import censored_line, few_levels

    t, d, q, inflation = case
    with no_warnings():
        fit = censored_line(t, d, q, inflation)
    event("few levels" if few_levels(d, q) else "many levels")
    if fit is None:
        return
    alpha, beta, cov = fit
    assert math.isfinite(alpha) and math.isfinite(beta) and np.isfinite(cov).all()
    for te in (t.min(), t.max()):
        assert d.min() - 2 * q <= alpha + beta * te <= d.max() + 2 * q
    np.testing.assert_allclose(cov, cov.T, rtol=1e-9, atol=1e-12)
    assert np.linalg.eigvalsh(cov).min() >= -1e-9 * max(1.0, float(np.abs(cov).max()))
