import math

import numpy as np
import pytest

from factories import flat_frame
from measure import Frame, MeasureError, MeasureOptions, PinholeCamera, measure_distance


def test_depth_from_disparity():
    f = flat_frame(d=10.0)
    assert np.allclose(f.depth(), 100.0 * 0.1 / 10.0)
    f2 = flat_frame(d=np.nan)
    assert np.isnan(f2.depth()).all()


def test_camera_scaled_roundtrip():
    cam = PinholeCamera(800.0, 800.0, 639.5, 359.5, 1280, 720)
    half = cam.scaled(640, 360)
    assert half.fx == 400.0 and half.cx == pytest.approx(319.5)
    assert half.scaled(1280, 720) == cam


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(disparity=np.zeros((48, 64), np.float64)), "float32"),
        (dict(disparity=np.zeros((48, 63), np.float32)), "63x48"),
        (dict(image=np.zeros((48, 64), np.uint8)), "uint8 BGR"),
        (dict(baseline_m=math.nan), "baseline_m"),
        (dict(baseline_m=-0.1), "positive"),
        (dict(confidence=np.zeros((48, 64), np.float64)), "confidence"),
    ],
)
def test_frame_rejects_bad_arrays(kw, match):
    w, h = 64, 48
    base = dict(
        image=np.zeros((h, w, 3), np.uint8),
        disparity=np.zeros((h, w), np.float32),
        camera=PinholeCamera(100.0, 100.0, 32.0, 24.0, w, h),
        baseline_m=0.1,
    )
    base.update(kw)
    with pytest.raises(MeasureError, match=match):
        Frame(**base)


def test_camera_rejects_nonfinite():
    with pytest.raises(MeasureError, match="fx"):
        PinholeCamera(math.inf, 100.0, 1.0, 1.0, 10, 10)


def test_options_validate():
    with pytest.raises(MeasureError, match="method"):
        MeasureOptions(method="magic")
    with pytest.raises(MeasureError, match="odd"):
        MeasureOptions(window=4)
    for bad in (-0.1, math.nan, math.inf, 50.5, True, "1.5", None):
        with pytest.raises(MeasureError, match=r"click_px=.* from 0 to 50 \(px\)"):
            MeasureOptions(click_px=bad)
    assert MeasureOptions(click_px=0).click_px == 0 and MeasureOptions(click_px=np.float32(50.0)).click_px == 50.0


def test_click_px_scales_only_the_uncertainty():
    # A tilted plane, clean: the click term is most of the sigma. The stated click error changes the
    # uncertainty (0: only the sensor's part), never the answer.
    from factories import plane_frame

    f = plane_frame(np.array([0.3, -0.1, 1.0]), 3.0)
    m = {c: measure_distance(f, (30.0, 60.0), (290.0, 170.0), MeasureOptions(click_px=c)) for c in (0.0, 1.5, 3.0, 6.0)}
    assert len({x.distance_m for x in m.values()}) == 1
    sig = [m[c].uncertainty_m for c in (0.0, 1.5, 3.0, 6.0)]
    assert sig[0] < sig[1] < sig[2] < sig[3], sig
    # Beyond the sensor's part the click term is linear in click_px: 6 px four times 1.5 px (1e-3: the
    # floor MIN_RELATIVE_SIGMA holds the exact clicks' sigma).
    assert (sig[3] ** 2 - sig[0] ** 2) == pytest.approx(16 * (sig[1] ** 2 - sig[0] ** 2), rel=1e-3)


def test_basic_on_fronto_parallel_plane():
    f = flat_frame(d=10.0)  # Z = 1 m everywhere
    m = measure_distance(f, (10, 20), (50, 20), MeasureOptions(method="basic"))
    assert m.distance_m == pytest.approx(40 / 100.0 * 1.0)


def test_valid_disparity_is_the_sum_rule_at_its_edges():
    """Frame.valid tests d > -doffs without the sum: the same verdict as d + doffs > 0 at -doffs and one
    rounding step either side, on NaN, infinities and float32 values whose sum overflows."""
    for doffs in (0.0, 2.75, -3.25, np.float64(7.1), 273.9):
        d = np.full((48, 64), 10.0, np.float32)
        edge = np.float32(-np.float32(doffs))
        d[0, :8] = [np.nan, np.inf, -np.inf, 3.4e38, edge, np.nextafter(edge, np.float32(1e9)), np.nextafter(edge, np.float32(-1e9)), 65.0]
        frame = Frame(np.zeros((48, 64, 3), np.uint8), d, PinholeCamera(60.0, 60.0, 31.5, 23.5, 64, 48), 0.1, doffs=doffs)
        for arr in (d, d.astype(np.float64)):
            with np.errstate(invalid="ignore", over="ignore"):
                expected = np.isfinite(arr) & (arr + doffs > 0) & (arr <= 64)
            assert np.array_equal(frame.valid(arr), expected), doffs
        if type(doffs) is float:  # a Python float is rounded to float32 with d: -doffs is the edge exactly
            assert frame.valid(d)[0, :8].tolist() == [False, False, False, False, False, True, False, False]
