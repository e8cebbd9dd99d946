"""`bag:` conversions against whole-array numpy formulations: the compiled z-buffer splat and the
whole-array NaN fill give the same bits (NaN payloads aside) on the bag fixtures' depth."""

from __future__ import annotations

import numpy as np
import pytest

from bag_writers import DEPTH_SHIFT_M
from device.sources.bag import MAX_SPLAT_PX, Rigid, align_depth_to_color
from device.sources.bag.messages import pixels_to_disparity, pixels_to_metres
from measure import PinholeCamera


def _numpy_align(depth_m: np.ndarray, depth_cam: PinholeCamera, color_cam: PinholeCamera, T: Rigid) -> np.ndarray:
    """The registration as whole-array numpy (footprints in float32 in the kernel's order of operations,
    ``np.minimum.at`` z-buffers per footprint offset): the oracle."""
    z_d = np.asarray(depth_m).astype(np.float32)
    v, u = np.nonzero(np.isfinite(z_d) & (z_d > 0))
    z = z_d[v, u]
    R, t = T.rotation, T.translation.astype(np.float32)
    fx, fy, cx, cy = (np.float32(a) for a in (color_cam.fx, color_cam.fy, color_cam.cx, color_cam.cy))
    u, v = u.astype(np.float64), v.astype(np.float64)

    def to_color(do: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        xn = (u + do - depth_cam.cx) / depth_cam.fx
        yn = (v + do - depth_cam.cy) / depth_cam.fy
        ray = [(R[i, 0] * xn + R[i, 2]).astype(np.float32) + (R[i, 1] * yn).astype(np.float32) for i in range(3)]
        Z = z * ray[2] + t[2]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return fx * (z * ray[0] + t[0]) / Z + cx, fy * (z * ray[1] + t[1]) / Z + cy, Z

    xa, ya, _ = to_color(-0.5)
    xb, yb, _ = to_color(0.5)
    xc, yc, zc = to_color(0.0)
    one, half = np.float32(1.0), np.float32(0.5)
    with np.errstate(invalid="ignore"):
        x0, x1 = np.ceil(np.minimum(xa, xb)), np.ceil(np.maximum(xa, xb)) - one
        y0, y1 = np.ceil(np.minimum(ya, yb)), np.ceil(np.maximum(ya, yb)) - one
        primary = (x1 >= x0) & (y1 >= y0)
        x0, x1 = np.where(x1 < x0, np.floor(xc + half), x0), np.where(x1 < x0, np.floor(xc + half), x1)
        y0, y1 = np.where(y1 < y0, np.floor(yc + half), y0), np.where(y1 < y0, np.floor(yc + half), y1)
        keep = (zc > 0) & np.isfinite(x0 + x1 + y0 + y1)
        keep &= (x1 >= 0) & (x0 <= color_cam.width - 1) & (y1 >= 0) & (y0 <= color_cam.height - 1)
    x0, x1, y0, y1, zc, primary = (a[keep] for a in (x0, x1, y0, y1, zc, primary))
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    nx = np.minimum(x1.astype(np.int64) - x0 + 1, MAX_SPLAT_PX)
    ny = np.minimum(y1.astype(np.int64) - y0 + 1, MAX_SPLAT_PX)
    zbuf = np.full(color_cam.width * color_cam.height, np.inf, np.float32)
    fallback = zbuf.copy()
    for dy in range(int(ny.max(initial=0))):
        for dx in range(int(nx.max(initial=0))):
            xs, ys = x0 + dx, y0 + dy
            m = (nx > dx) & (ny > dy) & (xs >= 0) & (xs < color_cam.width) & (ys >= 0) & (ys < color_cam.height)
            spot, first = ys[m] * color_cam.width + xs[m], primary[m]
            np.minimum.at(zbuf, spot[first], zc[m][first].astype(np.float32))
            np.minimum.at(fallback, spot[~first], zc[m][~first].astype(np.float32))
    np.copyto(zbuf, fallback, where=np.isinf(zbuf))
    zbuf[np.isinf(zbuf)] = np.nan
    return zbuf.reshape(color_cam.height, color_cam.width)


def _cases(capture):
    """(depth, depth camera, colour camera, extrinsics) from the bag fixtures' frames."""
    cam, dcam = capture.frames[0].camera, capture.depth_cam
    a = np.deg2rad(3.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    for z_unreg, z_reg in zip(capture.depth_unreg_m, capture.depth_reg_m):
        yield z_unreg, dcam, cam, Rigid(t=(DEPTH_SHIFT_M, 0.0, 0.0))  # the Viewer bag: half resolution, 5 cm aside
        yield z_unreg.astype(np.float32), dcam, cam, Rigid()  # corners on colour pixel edges: rounding ties
        yield z_reg, cam, dcam, Rigid.from_arrays(R, np.array([-0.08, 0.01, 0.0]))  # finer depth (fallbacks), rotated
        yield z_reg, cam, cam, Rigid(t=(-DEPTH_SHIFT_M, 0.0, 0.0))  # occlusions: several footprints per pixel
        yield z_reg, cam, cam, Rigid.from_arrays(R, np.array([0.3, 0.0, -2.9]))  # points at and behind the colour camera


@pytest.fixture(scope="module")
def capture():
    from bag_writers import make_capture

    return make_capture()


def test_compiled_splat_equals_the_numpy_registration_bit_for_bit(capture) -> None:
    for z, dcam, ccam, T in _cases(capture):
        want = _numpy_align(z, dcam, ccam, T)
        got = align_depth_to_color(z, dcam, ccam, T)
        assert got.dtype == np.float32 and got.shape == want.shape
        assert np.array_equal(np.isnan(got), np.isnan(want)) and np.isfinite(want).sum() > 0.2 * want.size
        assert np.array_equal(got.view(np.uint32)[~np.isnan(got)], want.view(np.uint32)[~np.isnan(want)])
        # disparity in the same pass: the float32 division of the separate conversion
        k = ccam.fx * 0.05
        assert np.array_equal(align_depth_to_color(z, dcam, ccam, T, disparity_k=k), pixels_to_disparity(want, 1.0, ccam.fx, 0.05),
                              equal_nan=True)  # fmt: skip


def test_depth_units_go_to_the_registration_as_recorded(capture) -> None:
    """uint16 depth units with their unit give what their metres (``pixels_to_metres``) give, bit for bit."""
    for unit in (0.001, 0.0001):
        for z, dcam, ccam, T in list(_cases(capture))[:4]:
            codes = np.where(np.isfinite(z), np.rint(np.nan_to_num(z) / unit), 0).clip(0, 65535).astype(np.uint16)
            want = align_depth_to_color(pixels_to_metres(codes, unit), dcam, ccam, T, disparity_k=ccam.fx * 0.05)
            got = align_depth_to_color(codes, dcam, ccam, T, disparity_k=ccam.fx * 0.05, depth_unit_m=unit)
            assert np.array_equal(got, want, equal_nan=True) and np.isfinite(got).sum() > 0.2 * got.size


def test_the_oracle_can_tell_a_different_registration(capture) -> None:
    """The bit comparison above fails for a registration one rounding away (a footprint a pixel wider)."""
    z, dcam, ccam, T = next(_cases(capture))
    wider = Rigid(t=(DEPTH_SHIFT_M + 1e-4, 0.0, 0.0))  # 0.1 mm: under a pixel of shift everywhere
    assert not np.array_equal(_numpy_align(z, dcam, ccam, T), align_depth_to_color(z, dcam, ccam, wider), equal_nan=True)


def _masked_metres(px: np.ndarray, unit_m: float) -> np.ndarray:
    z = px.astype(np.float32)
    if px.dtype != np.float32:
        z *= np.float32(unit_m)
    with np.errstate(invalid="ignore"):
        z[~(px > 0)] = np.nan
    return z


def test_whole_array_nan_fill_equals_the_masked_conversions() -> None:
    rng = np.random.default_rng(5)
    codes = rng.integers(0, 65536, (90, 160)).astype(np.uint16)
    codes[rng.random(codes.shape) < 0.3] = 0
    codes[0, :4] = [0, 1, 65535, 2]
    metres = rng.normal(2.0, 3.0, (90, 160)).astype(np.float32)  # a third negative: no depth
    metres[rng.random(metres.shape) < 0.1] = np.nan
    metres[0, :7] = [np.inf, -np.inf, 0.0, -0.0, 1e-45, 3e38, -1e-45]
    for px in (codes, metres, codes.byteswap().view(codes.dtype.newbyteorder())):
        for unit in (0.001, 0.0001):
            want = _masked_metres(px, unit)
            assert np.array_equal(pixels_to_metres(px, unit), want, equal_nan=True)
            with np.errstate(divide="ignore", over="ignore"):
                disparity = np.float32(600.5 * 0.05 / (1.0 if px.dtype == np.float32 else unit)) / _masked_metres(px, 1.0)
            got = pixels_to_disparity(px, unit, 600.5, 0.05)
            assert got.dtype == np.float32 and np.array_equal(got, disparity, equal_nan=True)
