"""Distorted colour in bags: depthai-ros / librealsense publish the lens distortion in camera_info; frames
are resampled onto pinhole images so that clicked pixels back-project with K alone."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bag_writers import OAK_RATIONAL, find_marks, make_near_frame, write_distorted_oak_bag, write_distorted_viewer_bag
from device import open_source
from device.sources.bag import BagError, Distortion, distortion_from_info, undistort_maps
from measure import MeasureOptions, PinholeCamera, measure_distance

CAM = PinholeCamera(fx=500.0, fy=500.0, cx=319.5, cy=179.5, width=640, height=360)


@pytest.mark.parametrize("model, coeffs", [("rational_polynomial", OAK_RATIONAL),
                                           ("plumb_bob", (-0.25, 0.07, 0.0005, -0.0003, -0.01))])
def test_poster_width_measured_where_the_user_clicks_on_a_distorted_bag(tmp_path, model, coeffs):
    """The user clicks the dots on the poster's end points in the image the source delivers. Before the
    distortion was undone the dots sat 6 px inwards and the 0.838 m width came out 2.8 cm short."""
    truth_frame, _ = make_near_frame()
    truth = truth_frame.meta["truth"]
    path = write_distorted_oak_bag(tmp_path / "oak", coeffs, model)
    with open_source(f"bag:{path}") as src:
        frame = src.read()
        info = src.info
    assert frame.meta["color_distortion"] == model and frame.meta["undistorted"] is True
    assert (info.extra["color_distortion"], info.extra["depth_distortion"]) == (model, model)
    clicks = find_marks(frame.image)
    assert len(clicks) == 2
    # The dots are back where a pinhole camera of the frame's K sees them.
    assert np.allclose(clicks, [truth.p1_px, truth.p2_px], atol=0.5)
    m = measure_distance(frame, clicks[0], clicks[1], MeasureOptions(method="robust"))
    assert m.distance_m == pytest.approx(truth.length_m, abs=0.005)
    # Depth stayed registered to the colour through the same resampling.
    inner = np.s_[60:300, 100:540]
    ok = np.isfinite(frame.depth()[inner]) & np.isfinite(truth_frame.depth()[inner])
    assert ok.mean() > 0.6
    assert np.median(np.abs(frame.depth()[inner][ok] - truth_frame.depth()[inner][ok])) < 0.002


def test_viewer_bag_distorted_colour_over_rectified_depth(tmp_path):
    """librealsense records the colour stream distorted (its inverse model) and depth rectified: the colour
    is undistorted onto the depth's pinhole geometry before the clicks back-project."""
    truth_frame, _ = make_near_frame()
    truth = truth_frame.meta["truth"]
    with open_source(f"bag:{write_distorted_viewer_bag(tmp_path / 'viewer.bag')}") as src:
        frame = src.read()
    assert frame.meta["layout"] == "realsense-viewer" and frame.meta["color_distortion"] == "inverse_brown_conrady"
    clicks = find_marks(frame.image)
    assert np.allclose(clicks, [truth.p1_px, truth.p2_px], atol=0.5)
    m = measure_distance(frame, clicks[0], clicks[1], MeasureOptions(method="robust"))
    assert m.distance_m == pytest.approx(truth.length_m, abs=0.005)


def _info(model, d):
    return SimpleNamespace(distortion_model=model, d=list(d))


def test_distortion_models_read_from_camera_info():
    assert distortion_from_info(_info("plumb_bob", [0] * 5), "t").is_none
    assert undistort_maps(CAM, distortion_from_info(_info("plumb_bob", [0] * 5), "t")) is None
    d = distortion_from_info(_info("Brown Conrady", [-0.1, 0.01, 0, 0, 0]), "t")  # the Viewer's spelling
    assert d == Distortion("brown_conrady", (-0.1, 0.01, 0.0, 0.0, 0.0))
    # Any model with all-zero coefficients is no distortion (a RealSense depth stream's "Inverse Brown Conrady").
    assert distortion_from_info(_info("equidistant", [0, 0, 0, 0]), "t").is_none
    with pytest.raises(BagError, match="'equidistant' with 4 non-zero.*image_rect"):
        distortion_from_info(_info("equidistant", [0.1, 0.01, 0, 0]), "t")
    with pytest.raises(BagError, match="not finite"):
        distortion_from_info(_info("plumb_bob", [np.nan, 0, 0, 0, 0]), "t")


def test_inverse_brown_conrady_maps_invert_librealsense_deprojection():
    """librealsense's colour model maps distorted to undistorted coordinates; the map must send each
    pinhole pixel to the distorted pixel that model takes back onto it."""
    k1, k2, p1, p2, k3 = c = (0.12, -0.2, 0.001, -0.0008, 0.08)
    mx, my = undistort_maps(CAM, Distortion("inverse_brown_conrady", c))
    x, y = (mx.astype(np.float64) - CAM.cx) / CAM.fx, (my.astype(np.float64) - CAM.cy) / CAM.fy
    r2 = x * x + y * y
    f = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    ux = (x * f + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)) * CAM.fx + CAM.cx
    uy = (y * f + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)) * CAM.fy + CAM.cy
    u, v = np.meshgrid(np.arange(CAM.width), np.arange(CAM.height))
    assert np.abs(ux - u).max() < 0.01 and np.abs(uy - v).max() < 0.01
    assert np.abs(mx - u).max() > 3  # the distortion is not negligible at the corners


def test_modified_brown_conrady_is_librealsense_projection():
    """librealsense's D400 colour model: radial first, tangential on the radially distorted point. Without
    tangential terms it is plumb_bob; with them the two differ, and the map follows librealsense."""
    radial = (-0.1, 0.03, 0.0, 0.0, 0.004)
    plumb = undistort_maps(CAM, Distortion("plumb_bob", radial))
    modified = undistort_maps(CAM, distortion_from_info(_info("Modified Brown Conrady", radial), "t"))
    assert np.abs(plumb[0] - modified[0]).max() < 1e-3 and np.abs(plumb[1] - modified[1]).max() < 1e-3
    k1, k2, p1, p2, k3 = c = (-0.1, 0.03, 0.004, -0.003, 0.004)
    mx, my = undistort_maps(CAM, Distortion("modified_brown_conrady", c))
    x, y = (639 - CAM.cx) / CAM.fx, (359 - CAM.cy) / CAM.fy  # the bottom-right pixel, by librealsense's formula
    r2 = x * x + y * y
    f = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    x, y = x * f, y * f
    want = (x + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)) * CAM.fx + CAM.cx, (y + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)) * CAM.fy + CAM.cy
    assert (mx[359, 639], my[359, 639]) == pytest.approx(want, abs=1e-3)
    opencv = undistort_maps(CAM, Distortion("plumb_bob", c))
    assert abs(opencv[0][359, 639] - mx[359, 639]) > 0.01  # the order of the terms shows at the corner
