"""`bag:` geometry: depth registered to the colour camera against the ray caster's truth, and time pairing."""

from __future__ import annotations

import numpy as np

from bag_writers import H, W
from device.sources.bag import Rigid, align_depth_to_color, pair_by_time
from measure import PinholeCamera
from sim.raycast import Pose, cast
from sim.scenes import SceneParams, build_scene, get_view


def test_align_handles_rotation_and_occlusion() -> None:
    """Pure geometry against the ray caster: a depth camera rotated 3 degrees about y and moved 8 cm, at
    half resolution; aligned to the colour camera it must give the colour camera's true depth (nearest
    surface wins where the board hides the wall)."""
    params = SceneParams("poster", distance_m=2.0, width=W, height=H, standoff_m=1.0)
    spec = build_scene(params)
    view_c = get_view(params)
    a = np.deg2rad(3.0)
    R_cd = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])  # depth axes in colour frame
    t_cd = np.array([-0.08, 0.01, 0.0])  # depth centre in the colour frame
    pose_c = view_c.pose
    pose_d = Pose(centre=tuple(pose_c.C + pose_c.R @ t_cd), rotation=tuple(map(tuple, pose_c.R @ R_cd)))
    cam_d = PinholeCamera(fx=260.0, fy=260.0, cx=159.5, cy=89.5, width=320, height=180)
    z_d = cast(spec.prims, cam_d, pose_d).depth
    z_d = np.where(np.isfinite(z_d), z_d, np.nan)
    T = Rigid.from_arrays(R_cd, t_cd)  # p_c = R_cd p_d + t_cd
    z = align_depth_to_color(z_d, cam_d, view_c.camera, T)
    zt = view_c.depth
    both = np.isfinite(z) & np.isfinite(zt)
    assert both.sum() > 0.8 * np.isfinite(zt).sum()
    rel = np.abs(z[both] - zt[both]) / zt[both]
    assert np.mean(rel < 0.01) > 0.97 and np.median(rel) < 0.002, (np.mean(rel < 0.01), np.median(rel))
    # The inverse reading of the extrinsics is visibly wrong: the check can fail.
    z_bad = align_depth_to_color(z_d, cam_d, view_c.camera, T.inverse())
    both_bad = np.isfinite(z_bad) & np.isfinite(zt)
    assert np.mean(np.abs(z_bad[both_bad] - zt[both_bad]) / zt[both_bad] < 0.01) < 0.9
    # invalid stays invalid: no depth in, no depth out
    assert np.isnan(align_depth_to_color(np.zeros_like(z_d), cam_d, view_c.camera, T)).all()


def test_pair_by_time_bounds_the_skew() -> None:
    c = np.array([0, 100, 200, 300, 400])
    d = np.array([3, 96, 260, 399, 1000])
    ci, di = pair_by_time(c, d, 10)
    assert ci.tolist() == [0, 1, 4] and di.tolist() == [0, 1, 3]  # 300 has none within 10
    assert pair_by_time(c, np.zeros(0, np.int64), 10)[0].size == 0


def test_finer_depth_is_not_biased_towards_the_camera() -> None:
    """Depth at twice the colour resolution (four depth pixels per colour pixel) of a noisy plane: each
    colour pixel takes one sample, so the aligned depth keeps the plane's mean (taking the nearest of
    the four would pull it ~1 sigma towards the camera) and no pixel of the plane is left empty."""
    color = PinholeCamera(fx=300.0, fy=300.0, cx=79.5, cy=59.5, width=160, height=120)
    depth_cam = PinholeCamera(fx=600.0, fy=600.0, cx=159.5, cy=119.5, width=320, height=240)
    sigma = 0.02
    z = 2.0 + np.random.default_rng(3).normal(0.0, sigma, (240, 320))
    aligned = align_depth_to_color(z, depth_cam, color, Rigid(t=(0.001, 0.0, 0.0)))
    inner = aligned[:, 2:-2]
    assert np.isfinite(inner).all()
    assert abs(np.mean(inner) - 2.0) < 0.1 * sigma, np.mean(inner) - 2.0


def test_registered_disparity_in_one_float32_pass_matches_the_float64_conversion():
    from device.sources.bag.messages import pixels_to_disparity, pixels_to_metres

    raw = np.array([[0, 1, 700, 65535], [2999, 3000, 12345, 0]], np.uint16)
    with np.errstate(divide="ignore"):
        want = np.where(raw > 0, 600.0 * 0.05 / (raw * 0.001), np.nan).astype(np.float32)
    got = pixels_to_disparity(raw, 0.001, 600.0, 0.05)
    assert got.dtype == np.float32
    assert np.array_equal(np.isnan(got), raw == 0)
    assert np.allclose(got, want, rtol=2e-7, equal_nan=True)  # within a float32 rounding step
    z = pixels_to_metres(np.array([[0.0, -1.0, np.nan, 2.5]], np.float32), 0.001)  # 32FC1: metres as they are
    assert np.array_equal(z, np.array([[np.nan, np.nan, np.nan, 2.5]], np.float32), equal_nan=True)
