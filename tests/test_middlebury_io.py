import numpy as np
import pytest

from device import SourceNotFound, open_source
from device.errors import CalibrationError
from device.middlebury import load_scene, read_pfm
from device.sgbm import SGBMConfig, compute_disparity


def test_pfm_roundtrip(tmp_path):
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    img[0, 0] = np.inf
    p = tmp_path / "x.pfm"
    with p.open("wb") as f:
        f.write(b"Pf\n4 3\n-1.0\n")
        f.write(np.flipud(img).astype("<f4").tobytes())
    out = read_pfm(p)
    assert np.isnan(out[0, 0])
    assert np.array_equal(out[1:], img[1:])


def test_truncated_pfm(tmp_path):
    p = tmp_path / "x.pfm"
    p.write_bytes(b"Pf\n4 3\n-1.0\n" + b"\0" * 10)
    with pytest.raises(CalibrationError, match="truncated"):
        read_pfm(p)


def test_scene_depth_is_metric(middlebury_dir):
    scene = load_scene(middlebury_dir / "Adirondack")
    z = scene.camera.fx * scene.baseline_m / (scene.gt_disparity + scene.doffs)
    # README: depth range across the scenes is roughly 1.1-8.6 m
    assert 1.0 < np.nanmin(z) and np.nanmax(z) < 9.0
    assert scene.camera.width == scene.left.shape[1]


def test_sgbm_matches_ground_truth_on_most_pixels(middlebury_dir):
    scene = load_scene(middlebury_dir / "Teddy")
    disp, conf = compute_disparity(scene.left, scene.right, SGBMConfig(num_disparities=64))
    m = scene.nonocc_mask & np.isfinite(disp)
    within = np.abs(disp[m] - scene.gt_disparity[m]) <= 1.0
    assert within.mean() > 0.8
    assert set(np.unique(conf)) <= {0.0, 1.0}


def test_source_spec(middlebury_dir):
    with open_source(f"middlebury:{middlebury_dir / 'Teddy'}?disparity=gt") as src:
        f = src.read()
    assert np.array_equal(f.disparity, f.meta["gt_disparity"], equal_nan=True)
    with pytest.raises(SourceNotFound, match="im0.png"):
        open_source(f"middlebury:{middlebury_dir}")
