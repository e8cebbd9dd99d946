"""V4L2 stereo pair: the real processing driven with Middlebury and rendered pairs through the grabber."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from device import CalibrationError, SourceDisconnected, SourceError, SourceNotFound, SourceSpec, SourceTimeout
from device import open_source
from device.calibration import StereoCalibration, render_board_view
from device.calibration_files import CalibrationRef
from device.middlebury import load_scene, read_calib
from device.sgbm import SGBMConfig, round_up_disparities
from device.stereo_pair import (
    ImagePairGrabber,
    StereoPairConfig,
    StereoPairSource,
    V4L2Grabber,
    config_from_spec,
    rectification,
)

# Share of non-occluded ground-truth pixels whose SGBM disparity (default SGBMConfig:
# sgbm_3way, block 5, P1/P2 8/32*3*bs^2, left band filled) is within 1 px, measured 2026-11-23
# (quarter-size MiddEval3 training scenes). Missing disparity counts as a miss. "raw": images
# used as they are (already rectified); "rectify": through cv2.stereoRectify (alpha=0 zooms in,
# so 1 px is a tighter bound there and the share is lower). Without the left-band fill the raw
# shares were 0.04-0.09 lower (0.589 Shelves to 0.849 Motorcycle).
SHARE_RAW = {"Adirondack": 0.861, "Motorcycle": 0.916, "Piano": 0.752, "Pipes": 0.865,
             "Playroom": 0.784, "Recycle": 0.881, "Shelves": 0.624, "Teddy": 0.892}
SHARE_RECTIFY = {"Motorcycle": 0.859, "Pipes": 0.823, "Teddy": 0.810}
MARGIN = 0.02


def _scene_calibration(path, scene, rectified: bool) -> StereoCalibration:
    calib = read_calib(path / "calib.txt")
    h, w = scene.left.shape[:2]
    return StereoCalibration(image_size=(w, h), K1=calib["cam0"], D1=np.zeros(5), K2=calib["cam1"], D2=np.zeros(5),
                             R=np.eye(3), T=np.array([-scene.baseline_m, 0.0, 0.0]), extra={"rectified": rectified})


def test_missing_devices_raise_not_found():
    if os.path.exists("/dev/video0"):
        pytest.skip("/dev/video0 exists on this machine")
    with pytest.raises(SourceNotFound, match="no V4L2 device /dev/video0.*--source sim"):
        open_source("v4l2:/dev/video0")
    with pytest.raises(SourceNotFound, match="/dev/video0"):
        open_source("v4l2:/dev/video0,/dev/video2?calib=rig.json")
    with pytest.raises(SourceNotFound, match="cannot open /dev/null as a V4L2 camera"):
        open_source("v4l2:/dev/null")  # exists, but is no camera: isOpened() is False


def test_spec_parsing():
    cfg = config_from_spec(SourceSpec.parse("v4l2:/dev/video0?layout=side-by-side&calib=rig.json&size=2560x960"
                                            "&fps=15&mode=hh&ndisp=96&block=7&wls=1&scale=0.5"))
    assert cfg.devices == ("/dev/video0",) and cfg.layout == "side-by-side" and cfg.calibration.path == "rig.json"
    assert (cfg.width, cfg.height, cfg.fps, cfg.scale, cfg.eye_size) == (2560, 960, 15.0, 0.5, (1280, 960))
    assert (cfg.sgbm.mode, cfg.sgbm.num_disparities, cfg.sgbm.block_size, cfg.sgbm.wls) == ("hh", 96, 7, True)
    two = config_from_spec(SourceSpec.parse("v4l2:/dev/video0,/dev/video2?calib=rig.json&fourcc=yuyv"))
    assert two.devices == ("/dev/video0", "/dev/video2") and two.layout == "two-nodes" and two.fourcc == "YUYV"
    assert two.eye_size == (640, 480)
    assert StereoPairConfig().eye_size == (640, 480)  # the live-view default (bench/RESULTS.md)
    assert StereoPairConfig().sgbm.fill_left_band
    assert not config_from_spec(SourceSpec.parse("v4l2:/dev/video0?fill_left_band=0")).sgbm.fill_left_band
    with pytest.raises(SourceError, match="unknown v4l2 option 'exposure'"):
        config_from_spec(SourceSpec.parse("v4l2:/dev/video0?exposure=3"))
    with pytest.raises(SourceError, match="mode"):
        config_from_spec(SourceSpec.parse("v4l2:/dev/video0?mode=fast"))
    with pytest.raises(SourceError, match="multiple of 16"):
        config_from_spec(SourceSpec.parse("v4l2:/dev/video0?ndisp=50"))
    with pytest.raises(SourceError, match="needs 2 device"):
        StereoPairConfig(devices=("/dev/video0",), layout="two-nodes")


@pytest.mark.parametrize("name", sorted(SHARE_RAW))
def test_middlebury_through_pipeline(middlebury_dir, name):
    path = middlebury_dir / name
    scene = load_scene(path)
    sgbm = SGBMConfig(num_disparities=round_up_disparities(scene.ndisp))
    src = StereoPairSource(StereoPairConfig(sgbm=sgbm), grabber=ImagePairGrabber([(scene.left, scene.right)]),
                           calibration=_scene_calibration(path, scene, rectified=True))
    with src:
        frame = src.read()
        with pytest.raises(SourceDisconnected):
            src.read()  # one pair only: end of data
    m = scene.nonocc_mask
    share = float(np.mean(np.abs(frame.disparity[m] - scene.gt_disparity[m]) <= 1.0))
    print(f"{name}: {share:.3f} of non-occluded pixels within 1 px")
    assert share >= SHARE_RAW[name] - MARGIN
    assert frame.doffs == pytest.approx(scene.doffs, abs=0.01) and frame.baseline_m == pytest.approx(scene.baseline_m)
    assert frame.camera == scene.camera and np.array_equal(frame.image, scene.left)
    # Depth follows Middlebury's Z = f B / (d + doffs): median relative error on good pixels is small.
    gt_z = scene.camera.fx * scene.baseline_m / (scene.gt_disparity + scene.doffs)
    good = m & np.isfinite(frame.disparity)
    assert np.median(np.abs(frame.depth()[good] / gt_z[good] - 1)) < 0.01
    conf = frame.confidence
    assert conf.shape == m.shape and conf.min() >= 0 and conf.max() <= 1
    assert (conf[~np.isfinite(frame.disparity)] == 0).all()


@pytest.mark.parametrize("name", sorted(SHARE_RECTIFY))
def test_middlebury_through_rectification(middlebury_dir, name):
    path = middlebury_dir / name
    scene = load_scene(path)
    calib = _scene_calibration(path, scene, rectified=False)
    h, w = scene.left.shape[:2]
    rect = rectification(calib, (w, h))
    assert rect.doffs == pytest.approx(0.0, abs=1e-6)  # CALIB_ZERO_DISPARITY
    s = rect.camera.fx / scene.camera.fx
    ndisp = round_up_disparities(int(np.ceil(s * (scene.ndisp + scene.doffs))))
    src = StereoPairSource(StereoPairConfig(sgbm=SGBMConfig(num_disparities=ndisp)),
                           grabber=ImagePairGrabber([(scene.left, scene.right)]), calibration=calib)
    with src:
        frame = src.read()
    # Ground truth seen from the rectified left camera: look up the source pixel through the
    # rectification map, take its true depth, and express it as rectified disparity fx' B' / Z.
    mx, my = rect.maps[0], rect.maps[1]
    gt = cv2.remap(scene.gt_disparity, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    mask = cv2.remap(scene.nonocc_mask.astype(np.uint8), mx, my, cv2.INTER_NEAREST).astype(bool) & np.isfinite(gt)
    z = scene.camera.fx * scene.baseline_m / (gt + scene.doffs)
    expected = rect.camera.fx * rect.baseline_m / z
    share = float(np.mean(np.abs(frame.disparity[mask] - expected[mask]) <= 1.0))
    print(f"{name} rectified: {share:.3f} within 1 px (zoom {s:.3f})")
    assert share >= SHARE_RECTIFY[name] - MARGIN
    assert frame.baseline_m == pytest.approx(scene.baseline_m, rel=1e-6)


def test_rendered_rig_with_rotation_gives_true_depth():
    """A textured wall 1.5 m in front of a rotated, offset pair: rectification + SGBM give its depth."""
    size, fx, z_wall = (640, 480), 700.0, 1.5
    K1 = np.array([[fx, 0, 320.5], [0, fx, 240.5], [0, 0, 1]])
    K2 = np.array([[705.0, 0, 315.0], [0, 705.0, 243.0], [0, 0, 1]])
    R, _ = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))
    T = np.array([-0.08, 0.002, 0.001])
    rng = np.random.default_rng(3)
    texture = cv2.resize(rng.integers(0, 255, (300, 400), dtype=np.uint8), (1600, 1200), interpolation=cv2.INTER_CUBIC)
    texture = cv2.GaussianBlur(texture, (0, 0), 1.5)
    p = 800.0  # texture pixels per metre: a 2 x 1.5 m wall centred on the left optical axis
    origin = np.array([-1.0, -0.75, z_wall])
    left = render_board_view(texture, p, 0, K1, [0, 0, 0], origin, size)
    rv, _ = cv2.Rodrigues(R)
    right = render_board_view(texture, p, 0, K2, rv.ravel(), R @ origin + T, size)
    calib = StereoCalibration(image_size=size, K1=K1, D1=np.zeros(5), K2=K2, D2=np.zeros(5), R=R, T=T)
    src = StereoPairSource(StereoPairConfig(sgbm=SGBMConfig(num_disparities=64)),
                           grabber=ImagePairGrabber([(cv2.cvtColor(left, cv2.COLOR_GRAY2BGR),
                                                      cv2.cvtColor(right, cv2.COLOR_GRAY2BGR))]), calibration=calib)
    with src:
        frame = src.read()
    assert frame.baseline_m == pytest.approx(np.linalg.norm(T), rel=1e-6)
    centre = frame.depth()[120:360, 160:480]
    valid = np.isfinite(centre)
    assert valid.mean() > 0.9
    # The rectified left camera is rotated slightly from the raw one, so the wall is not exactly
    # fronto-parallel there: compare the median, which sits at the image centre's depth.
    assert np.median(centre[valid]) == pytest.approx(z_wall, rel=0.01)


class _FakeCap:
    """A cv2.VideoCapture stand-in with scripted frames and device timestamps (ms)."""

    def __init__(self, stamps_ms, value):
        self.stamps = list(stamps_ms)
        self.value = value
        self.now = 0.0

    def read(self):
        if not self.stamps:
            return False, None
        self.now = self.stamps.pop(0)
        return True, np.full((4, 6, 3), self.value, np.uint8)

    def get(self, prop):
        return self.now if prop == cv2.CAP_PROP_POS_MSEC else 0.0

    def release(self):
        pass


def _two_node_grabber(left_ms, right_ms, max_skew_s=None) -> V4L2Grabber:
    g = V4L2Grabber(StereoPairConfig(devices=("/dev/video0", "/dev/video2"), layout="two-nodes", width=32, height=16,
                                     fps=30, max_skew_s=max_skew_s))
    g._caps = [_FakeCap(left_ms, 1), _FakeCap(right_ms, 2)]
    return g


def test_two_nodes_paired_by_timestamp():
    g = _two_node_grabber([1000, 1033, 1066, 1100], [1060, 1093])
    left, right, stamp = g.grab()  # L1000/R1060 too far apart: left catches up to L1066
    assert (left[0, 0, 0], right[0, 0, 0]) == (1, 2) and stamp == pytest.approx(1.063)
    left, right, stamp = g.grab()
    assert stamp == pytest.approx(1.0965)
    with pytest.raises(SourceDisconnected, match="/dev/video0"):
        g.grab()
    # Cameras 10 ms apart on every frame can never pair within a 5 ms bound.
    drifting = _two_node_grabber(list(range(1, 10**6, 33)), list(range(11, 10**6, 33)), max_skew_s=0.005)
    with pytest.raises(SourceTimeout, match="one fps for both"):
        drifting.grab(timeout_s=0.05)


def test_side_by_side_split():
    g = V4L2Grabber(StereoPairConfig(width=32, height=16))

    class Cap(_FakeCap):
        def read(self):
            self.now = 40.0
            return True, np.dstack([np.tile(np.r_[np.zeros(3), np.ones(3)], (4, 1))] * 3).astype(np.uint8)

    g._caps = [Cap([], 0)]
    left, right, stamp = g.grab()
    assert left.shape == right.shape == (4, 3, 3) and left.max() == 0 and right.min() == 1 and stamp == 0.04


def test_calibration_required_and_checked(tmp_path, middlebury_dir):
    scene = load_scene(middlebury_dir / "Teddy")
    grab = ImagePairGrabber([(scene.left, scene.right)])
    with pytest.raises(CalibrationError, match="add calib=FILE"):
        StereoPairSource(StereoPairConfig(), grabber=grab).open()
    with pytest.raises(CalibrationError, match="does not exist"):
        StereoPairSource(StereoPairConfig(calibration=CalibrationRef(str(tmp_path / "rig.json"))), grabber=grab).open()
    # Calibrated at 4:3, images 450x375 (6:5): refuse rather than measure with wrong intrinsics.
    cal = StereoCalibration(image_size=(640, 480), K1=np.eye(3), D1=np.zeros(5), K2=np.eye(3), D2=np.zeros(5),
                            R=np.eye(3), T=np.array([-0.1, 0, 0]))
    with StereoPairSource(StereoPairConfig(), grabber=grab, calibration=cal) as src:
        with pytest.raises(CalibrationError, match="aspect ratio"):
            src.read()
    # Left and right swapped: the right camera sits on the left.
    k = np.array([[500.0, 0, 225], [0, 500, 187], [0, 0, 1]])
    swapped = StereoCalibration(image_size=(450, 375), K1=k, D1=np.zeros(5), K2=k, D2=np.zeros(5), R=np.eye(3),
                                T=np.array([0.1, 0, 0]))
    with pytest.raises(CalibrationError, match="swap"):
        rectification(swapped, (450, 375))


@pytest.mark.hardware
def test_real_stereo_pair():
    spec = os.environ.get("DEPTHRULER_V4L2_SPEC", "v4l2:/dev/video0?calib=configs/calib/stereo.json")
    with open_source(spec) as src:
        frame = src.read(timeout_s=3.0)
    assert np.isfinite(frame.disparity).mean() > 0.2


@pytest.mark.parametrize("scene,distance", [("poster", 2.0), ("boxes", 3.0)])
def test_simulator_rendered_pair_through_pipeline(scene, distance):
    """The simulator's rendered stereo pair (exact ground truth) through the same grabber and processing."""
    sim_scenes = pytest.importorskip("sim.scenes")
    from sim.scenario import make_model
    from sim.stereo import stereo_pair, true_disparity

    from measure import MeasureOptions, measure_distance

    params = sim_scenes.SceneParams(scene=scene, distance_m=distance, width=640, height=480)
    model = make_model("indoor")
    left, right = stereo_pair(params, model, np.random.default_rng(0))
    view = sim_scenes.get_view(params)
    cam = view.camera
    k = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
    calib = StereoCalibration(image_size=(640, 480), K1=k, D1=np.zeros(5), K2=k, D2=np.zeros(5), R=np.eye(3),
                              T=np.array([-model.baseline_wide_m, 0, 0]), extra={"rectified": True})
    gt = true_disparity(params, model)
    sgbm = SGBMConfig(num_disparities=round_up_disparities(int(np.nanmax(gt) * 1.25) + 8))
    with StereoPairSource(StereoPairConfig(sgbm=sgbm), grabber=ImagePairGrabber([(left, right)]),
                          calibration=calib) as src:
        frame = src.read()
    # The simulator's textures and sky change as it evolves, so no coverage figure is pinned here:
    # where SGBM matched, it must agree with the exact disparity, and the length must come out right.
    matched = np.isfinite(gt) & np.isfinite(frame.disparity)
    assert matched.sum() > 0.3 * gt.size
    assert np.median(np.abs(frame.disparity[matched] - gt[matched])) < 0.5
    truth = view.truth()
    got = measure_distance(frame, truth.p1_px, truth.p2_px, MeasureOptions(method="basic")).distance_m
    assert got == pytest.approx(truth.length_m, rel=0.05)
