"""measure_distance: the paper's branches, the degenerate camera-centre plane, gaps, bad input, properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from measure import Frame, MeasureError, MeasureOptions, PinholeCamera, measure_distance
from measure.linefit import fit_line
from measure.sampling import backproject_depth, sample_segment
from measure.zonly import measure_z_only

from measure.metrics import accuracy
from factories import SMALL_B, SMALL_CAM, SMALL_F, SMALL_H, SMALL_W, doorway_frame, plane_frame, true_length
from measure_synth import poster_case

W, H, F, B = SMALL_W, SMALL_H, SMALL_F, SMALL_B
CAM = SMALL_CAM


# --- the paper's branches -------------------------------------------------------------------------

def test_paper_constant_depth_branch():
    """Integer disparity, fronto-parallel: >= h samples on Z = const (a = b = 0): Z of P1, P2 set to -d/c."""
    f = plane_frame((0.0, 0.0, 1.0), 3.0, quantum=1.0, outliers=0.3, seed=1)
    p1, p2 = (40.0, 50.0), (260.0, 190.0)
    m = measure_distance(f, p1, p2, MeasureOptions(method="paper", gap_detection=False))
    assert m.fit == "constant-depth"
    z = F * B / 10.0  # disparity 10 px exactly
    ends = backproject_depth(f, np.array([p1[0], p2[0]]), np.array([p1[1], p2[1]]), np.full(2, z))
    assert m.distance_m == pytest.approx(float(np.linalg.norm(ends[1] - ends[0])), rel=1e-9)
    assert m.p1_m[2] == pytest.approx(z) and m.p2_m[2] == pytest.approx(z)


def test_paper_plane_branch_projects_onto_the_exact_plane():
    """Exact disparity of a tilted plane on a diagonal segment: the samples are not on one image line,
    so the exact fit is the object's plane; P1, P2 are projected onto it (Eq. 4-5)."""
    normal, k = np.array([0.3, -0.2, 1.0]), 3.0
    f = plane_frame(normal, k)
    p1, p2 = (30.0, 40.0), (280.0, 170.0)
    m = measure_distance(f, p1, p2, MeasureOptions(method="paper", gap_detection=False))
    assert m.fit == "plane"
    assert m.distance_m == pytest.approx(true_length(f, normal, k, p1, p2), rel=2e-3)


def test_paper_line_branch_on_noisy_data():
    normal, k = np.array([0.2, 0.1, 1.0]), 2.5
    f = plane_frame(normal, k, noise=0.1, outliers=0.3, seed=2)
    p1, p2 = (30.0, 40.0), (280.0, 170.0)
    m = measure_distance(f, p1, p2, MeasureOptions(method="paper", gap_detection=False))
    assert m.fit == "line" and 0.5 * m.n_valid < m.n_support < m.n_valid
    assert accuracy(true_length(f, normal, k, p1, p2), m.distance_m) > 98.0


@pytest.mark.parametrize("noise", [0.0, 0.1])
@pytest.mark.parametrize("p1, p2", [((20.0, 120.0), (300.0, 120.0)), ((160.0, 10.0), (160.0, 230.0)), ((20.0, 20.0), (220.0, 220.0))])
def test_degenerate_camera_centre_plane(p1, p2, noise):
    """Samples on one image line (row, column, 45 degrees): every 3D point, outliers included, lies on the
    plane of the viewing rays through the camera centre (d = 0). It must not be taken as the surface.
    With exact depth the line inside that plane is itself an exact fit (>= h points on it); with noisy
    depth the line is fit robustly within the plane."""
    normal, k = np.array([0.4, -0.3, 1.0]), 3.0
    f = plane_frame(normal, k, noise=noise, seed=1)
    d = f.disparity.copy()
    rng = np.random.default_rng(0)
    d[rng.random(d.shape) < 0.3] *= 1.3  # outliers, still on their pixels' rays
    f = Frame(f.image, d, CAM, B)
    samples = sample_segment(f, p1, p2)
    model = fit_line(samples.points, 0.5, 0)
    assert model.kind == "line"
    if noise == 0.0:
        assert model.mcd.exact_fit and model.mcd.fit_kind == "line" and model.mcd.n_on_fit >= model.mcd.h
    else:
        assert model.degenerate_plane and model.mcd.exact_fit and model.mcd.n_on_fit == len(samples.points)
        assert abs(model.mcd.plane[3]) < 1e-9
    truth = true_length(f, normal, k, p1, p2)
    for method in ("paper", "robust"):
        m = measure_distance(f, p1, p2, MeasureOptions(method=method, gap_detection=False))
        assert m.fit == "line"
        # The paper projects window end points (30 % outliers in the window) onto a 3D TLS line.
        tol = {("robust", 0.0): 2e-3, ("robust", 0.1): 1e-2, ("paper", 0.0): 1e-2, ("paper", 0.1): 3e-2}[method, noise]
        assert m.distance_m == pytest.approx(truth, rel=tol), method


# --- gaps -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["paper", "robust"])
def test_gap_found_on_doorway(method):
    f = doorway_frame()
    p1, p2 = (99.0, 120.0), (220.0, 120.0)  # the jambs: last wall pixel each side
    m = measure_distance(f, p1, p2, MeasureOptions(method=method))
    assert m.gap_detected and m.fit == "none"
    truth = (p2[0] - p1[0]) * 3.0 / F
    assert accuracy(truth, m.distance_m) > 97.0


def test_no_gap_on_tilted_posters():
    rng = np.random.default_rng(42)
    gaps = {"robust": 0, "paper": 0}
    for i in range(12):
        case = poster_case(4.0 + (i % 4), rng, target="width" if i % 2 else "height", yaw_deg=rng.uniform(-40, 40), pitch_deg=rng.uniform(-20, 20), wall_gap_m=0.05)
        for method in gaps:
            gaps[method] += measure_distance(case.frame, case.click1, case.click2, MeasureOptions(method=method)).gap_detected
    assert gaps["robust"] == 0
    assert gaps["paper"] >= gaps["robust"]


@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_a_gaps_rounding_is_its_ends_whatever_lies_behind_it(noise):
    """Integer disparity (a camera without subpixel): the wall beside a doorway at 3 m is exactly 10 px,
    so each end surface is one level and its depth carries one rounding error, q / sqrt(12) px. The
    gap's sigma is that, propagated to the width, and does not grow with the depth of the room behind
    the door (it did: the rounding was the back wall's, at its depth and over its length)."""
    from measure import robust_with_terms
    from measure.gap import GAP_SIGMA_SCALE
    from measure.sampling import ray
    from measure.uncertainty import endpoint_depth_sigma

    p1, p2 = (99.0, 120.0), (220.0, 120.0)  # the last wall pixel each side
    z = F * B / 10.0
    q1, q2 = (np.array([(x - CAM.cx) / F, (y - CAM.cy) / F, 1.0]) * z for x, y in (p1, p2))
    rounding_m = z * z / (F * B) / math.sqrt(12.0)
    want = endpoint_depth_sigma(q1, q2, rounding_m, rounding_m)
    sigmas = []
    for back_z in (6.0, 12.0, 24.0):
        zmap = np.full((H, W), z)
        zmap[:, 100:220] = back_z
        d = F * B / zmap + np.random.default_rng(7).normal(0.0, noise, zmap.shape)  # < 0.5 px: no level change
        f = Frame(np.zeros((H, W, 3), np.uint8), np.round(d).astype(np.float32), CAM, B)
        m, terms = robust_with_terms(f, p1, p2, MeasureOptions(click_px=0.0))
        assert m.gap_detected and m.distance_m == pytest.approx(float(np.linalg.norm(q2 - q1)), rel=1e-9)
        assert np.allclose(m.p1_m, ray(f, *p1) * z) and terms["fit"] == 0.0  # one level: no scatter
        assert terms["quant"] == pytest.approx(want, rel=1e-6)
        sigmas.append(m.uncertainty_m)
    assert sigmas == pytest.approx([GAP_SIGMA_SCALE * want] * 3, rel=1e-6)


def test_gap_detection_can_be_switched_off():
    m = measure_distance(doorway_frame(), (99.0, 120.0), (220.0, 120.0), MeasureOptions(gap_detection=False))
    assert not m.gap_detected and m.fit != "none"


# --- end points without depth ---------------------------------------------------------------------

def test_robust_measures_when_an_endpoint_has_no_depth():
    normal, k = np.array([0.2, 0.0, 1.0]), 3.0
    f = plane_frame(normal, k, noise=0.05, seed=3)
    d = f.disparity.copy()
    d[:, :60] = np.nan  # no depth around p1
    f = Frame(f.image, d, CAM, B)
    p1, p2 = (40.0, 100.0), (290.0, 150.0)
    m = measure_distance(f, p1, p2)
    assert any("endpoint has no depth within window" in w for w in m.warnings)
    assert math.isnan(m.basic_distance_m)
    truth = true_length(f, normal, k, p1, p2)
    assert abs(m.distance_m - truth) < 3 * m.uncertainty_m + 1e-3
    with pytest.raises(MeasureError, match="no depth"):
        measure_distance(f, p1, p2, MeasureOptions(method="basic"))
    with pytest.raises(MeasureError, match="no depth"):
        measure_distance(f, p1, p2, MeasureOptions(method="paper"))


# --- every measurement reports ----------------------------------------------------------------------

@pytest.mark.parametrize("method", ["basic", "paper", "robust"])
def test_measurement_fields(method):
    f = plane_frame((0.1, 0.0, 1.0), 2.0, noise=0.1, quantum=0.25, seed=4)
    m = measure_distance(f, (30, 60), (290, 180), MeasureOptions(method=method))
    assert m.method == method and math.isfinite(m.distance_m) and m.uncertainty_m > 0
    assert math.isfinite(m.basic_distance_m) and len(m.p1_m) == 3 and len(m.p2_m) == 3
    assert m.samples_px.shape == (m.n_valid, 2) and m.support.shape == (m.n_valid,)
    assert m.n_support == m.support.sum() <= m.n_valid <= m.n_samples
    assert m.elapsed_ms > 0 and m.fit in {"line", "plane", "constant-depth", "none"}
    assert m.to_dict()["method"] == method


def test_z_only_ablation():
    normal, k = np.array([0.3, 0.0, 1.0]), 3.0
    f = plane_frame(normal, k, noise=0.1, outliers=0.2, seed=5)
    p1, p2 = (30.0, 100.0), (290.0, 120.0)
    m = measure_z_only(f, p1, p2)
    assert m.method == "z-only" and accuracy(true_length(f, normal, k, p1, p2), m.distance_m) > 97.0


# --- bad input ------------------------------------------------------------------------------------

def _frame():
    return plane_frame((0.0, 0.0, 1.0), 3.0)


@pytest.mark.parametrize(
    "p1, p2, match",
    [
        ((-1, 10), (100, 10), "outside"),
        ((10, 10), (W, 10), "outside"),
        ((10, 10), (10, 10), "same pixel"),
        ((10, 10), (12, 11), "too short"),
        ((float("nan"), 10), (100, 10), "not finite"),
        ((10, 10, 3), (100, 10), "pair"),
        ("ab", (100, 10), "pair"),
    ],
)
def test_bad_points(p1, p2, match):
    with pytest.raises(MeasureError, match=match):
        measure_distance(_frame(), p1, p2)


def test_bad_frames_and_options():
    f = _frame()
    wrong_dtype = Frame(f.image, f.disparity, CAM, B)
    object.__setattr__(wrong_dtype, "disparity", f.disparity.astype(np.float64))
    with pytest.raises(MeasureError, match="float32"):
        measure_distance(wrong_dtype, (10, 10), (100, 10))
    wrong_shape = Frame(f.image, f.disparity, CAM, B)
    object.__setattr__(wrong_shape, "disparity", f.disparity[:, :-1])
    with pytest.raises(MeasureError, match="disparity is"):
        measure_distance(wrong_shape, (10, 10), (100, 10))
    cam = PinholeCamera(F, F, 1.0, 1.0, W, H)
    object.__setattr__(cam, "fx", math.nan)
    bad_cam = Frame(f.image, f.disparity, CAM, B)
    object.__setattr__(bad_cam, "camera", cam)
    with pytest.raises(MeasureError, match="fx"):
        measure_distance(bad_cam, (10, 10), (100, 10))
    with pytest.raises(MeasureError, match="MeasureOptions"):
        measure_distance(f, (10, 10), (100, 10), {"method": "robust"})
    with pytest.raises(MeasureError, match="Frame"):
        measure_distance("frame", (10, 10), (100, 10))


def test_no_valid_disparity_near_the_line():
    f = _frame()
    d = f.disparity.copy()
    d[50:70, :] = np.nan
    f = Frame(f.image, d, CAM, B)
    with pytest.raises(MeasureError, match="no valid disparity"):
        measure_distance(f, (10, 60), (300, 60))


# --- properties -----------------------------------------------------------------------------------

_PROPERTY_FRAME = plane_frame((0.25, -0.1, 1.0), 3.0, noise=0.15, quantum=0.25, outliers=0.3, seed=9)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    x1=st.floats(5, 150), y1=st.floats(5, 230), x2=st.floats(170, 314), y2=st.floats(5, 230),
    method=st.sampled_from(["basic", "paper", "robust"]),
)
def test_swapping_the_clicks_changes_nothing(x1, y1, x2, y2, method):
    f = _PROPERTY_FRAME
    a = measure_distance(f, (x1, y1), (x2, y2), MeasureOptions(method=method))
    b = measure_distance(f, (x2, y2), (x1, y1), MeasureOptions(method=method))
    assert b.distance_m == pytest.approx(a.distance_m, rel=2e-3)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), x1=st.floats(5, 100), x2=st.floats(220, 314), y=st.floats(20, 220))
def test_seed_does_not_matter_on_well_posed_data(seed, x1, x2, y):
    f = _PROPERTY_FRAME
    a = measure_distance(f, (x1, y), (x2, 240 - y), MeasureOptions(seed=0))
    b = measure_distance(f, (x1, y), (x2, 240 - y), MeasureOptions(seed=seed))
    assert abs(a.distance_m - b.distance_m) <= max(0.2 * a.uncertainty_m, 1e-4 * a.distance_m)


@given(st.lists(st.sampled_from([-0.0, 0.0, 1.0, 1.25, 1.5, 2.0, 7.0625, 30.0, 30.25]), max_size=40))
def test_quantum_and_levels_are_those_of_the_distinct_values(values):
    """The disparity quantum and the count of levels from the sorted values' positive steps are
    np.unique's (which counts -0.0 and 0.0 as one value)."""
    from measure.uncertainty import disparity_quantum, distinct_levels

    u = np.unique(np.array(values, dtype=np.float64))
    assert distinct_levels(np.array(values, dtype=np.float32)) == u.size
    assert disparity_quantum(np.array(values)) == (min(1.0, float(np.diff(u).min())) if u.size > 1 else 1.0)
