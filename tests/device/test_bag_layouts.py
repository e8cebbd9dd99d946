"""`bag:` layouts: ROS 1 and ROS 2 bags (MCAP, sqlite3) in the RealSense Viewer, realsense-ros and depthai-ros
layouts and named topics, written from simulated frames and measured against the simulator's truth and
the same frames through `replay:`."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bag_writers import (
    DEPTH_SHIFT_M,
    H,
    N_FRAMES,
    PERIOD,
    T0,
    W,
    BagOut,
    Capture,
    _header,
    abs_errors,
    depth_array,
    image_msg,
    info_msg,
    make_capture,
    read_all,
    write_ros_bag,
    write_viewer_bag,
)
from device import SourceError, make_source, open_source
from device.base import SourceInfo
from device.formats.recording import RecordingWriter
from device.sources.bag import BagError, BagLayoutError, Rigid, align_depth_to_color


@pytest.fixture(scope="module")
def capture() -> Capture:
    return make_capture()


@pytest.fixture(scope="module")
def replay_errors(capture: Capture, tmp_path_factory) -> np.ndarray:
    """The same frames through the project's own recorder and `replay:`: the accuracy to match."""
    path = tmp_path_factory.mktemp("rec") / "rec"
    with RecordingWriter(path, SourceInfo(kind="sim", name="sim")) as w:
        for f in capture.frames:
            w.write(f)
    with open_source(f"replay:{path}") as src:
        got = [src.read() for _ in range(N_FRAMES)]
    return abs_errors(zip(got, capture.frames))


def test_replay_reference_is_accurate(replay_errors: np.ndarray) -> None:
    assert replay_errors.max() < 0.02, replay_errors  # the poster's width at 3 m within 2 cm


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_realsense_ros_registered_matches_replay(capture, replay_errors, tmp_path: Path, kind: str, encoding: str) -> None:
    bag = write_ros_bag(tmp_path / "rs", capture, kind, "realsense-ros", encoding=encoding)
    frames = read_all(f"bag:{bag}")
    assert len(frames) == N_FRAMES
    for k, f in enumerate(frames):
        assert f.meta["layout"] == "realsense-ros" and f.meta["registered_in_bag"]
        assert f.meta["depth_unit_m"] == (None if encoding == "32FC1" else 0.001)
        assert np.array_equal(f.image, capture.frames[k].image)
        assert f.camera == capture.frames[k].camera
        ref = capture.depth_reg_m[k]
        # Invalid stays invalid, and valid depth comes back within its unit (1 mm; float32 for 32FC1).
        assert np.array_equal(np.isnan(f.depth()), depth_array(ref, "16UC1") == 0 if encoding == "16UC1" else np.isnan(ref))
        ok = np.isfinite(f.depth())
        assert np.max(np.abs(f.depth()[ok] - ref[ok])) <= (0.0005 + 1e-9 if encoding == "16UC1" else 1e-5)
        assert f.timestamp == pytest.approx((T0 + k * PERIOD) / 1e9)
        assert abs(f.meta["skew_s"]) < 1e-9  # paired by bag time (25 ms apart), checked by header stamps
    errs = abs_errors(zip(frames, capture.frames))
    assert np.all(errs <= replay_errors + 0.001), (errs, replay_errors)


def test_depthai_ros_mcap_registered(capture, replay_errors, tmp_path: Path) -> None:
    bag = write_ros_bag(tmp_path / "oak", capture, "mcap", "depthai-ros")
    frames = read_all(f"bag:{bag}")
    assert [f.meta["layout"] for f in frames] == ["depthai-ros"] * N_FRAMES
    errs = abs_errors(zip(frames, capture.frames))
    assert np.all(errs <= replay_errors + 0.001), (errs, replay_errors)
    # a single .mcap file opens too (the file inside the folder)
    assert len(read_all(f"bag:{next(bag.glob('*.mcap'))}")) == N_FRAMES


def aligned_share(frames, capture: Capture) -> tuple[float, float]:
    """Over the colour camera's true depth: the share of pixels whose aligned depth is within 1 % of it,
    and the share that have aligned depth at all (bags written from noise-free depth)."""
    zt = capture.frames[0].meta["truth"].depth_m
    good, covered = [], []
    for f in frames:
        z = f.depth()
        both = np.isfinite(z) & np.isfinite(zt)
        good.append(np.mean(np.abs(z[both] - zt[both]) < 0.01 * zt[both]))
        covered.append(both.sum() / np.isfinite(zt).sum())
    return float(np.mean(good)), float(np.mean(covered))


def test_viewer_bag_unregistered_depth_is_aligned(capture, replay_errors, tmp_path: Path) -> None:
    bag = write_viewer_bag(tmp_path / "viewer.bag", capture)
    frames = read_all(f"bag:{bag}")
    assert len(frames) == N_FRAMES
    f = frames[0]
    assert f.meta["layout"] == "realsense-viewer" and not f.meta["registered_in_bag"] and f.meta["extrinsics"] == "viewer tf"
    assert f.meta["depth_unit_m"] == pytest.approx(0.0001) and f.baseline_m == pytest.approx(0.05)  # recorded options
    assert f.image.shape == (H, W, 3) and np.array_equal(f.image, capture.frames[0].image)
    errs = abs_errors(zip(frames, capture.frames))
    # Other sensor noise (the depth camera's own), half the resolution and the occlusion holes of a camera
    # 5 cm to the left: as accurate as the registered frames through replay, within a centimetre.
    assert np.mean(errs) <= np.mean(replay_errors) + 0.01, (errs, replay_errors)
    assert errs.max() < 0.03, errs
    good, covered = aligned_share(read_all(f"bag:{write_viewer_bag(tmp_path / 'exact.bag', capture, noise_free=True)}"), capture)
    assert good > 0.99 and covered > 0.97, (good, covered)


def test_viewer_bag_of_the_same_frames_matches_replay(capture, replay_errors, tmp_path: Path) -> None:
    """The simulated frames' own depth, as a full-resolution depth camera 5 cm to the left saw it (warped there
    with the inverse extrinsics), aligned back by the bag source: as accurate as the frames through replay."""
    cam = capture.frames[0].camera
    to_depth = Rigid(t=(DEPTH_SHIFT_M, 0.0, 0.0)).inverse()
    warped = [align_depth_to_color(z, cam, cam, to_depth) for z in capture.depth_reg_m]
    frames = read_all(f"bag:{write_viewer_bag(tmp_path / 'same.bag', capture, depth=(cam, warped))}")
    errs = abs_errors(zip(frames, capture.frames))
    assert np.all(errs <= replay_errors + 0.002), (errs, replay_errors)
    for f, z in zip(frames, capture.depth_reg_m):  # what both cameras see comes back unchanged (to 0.1 mm units)
        both = np.isfinite(f.depth()) & np.isfinite(z)
        assert both.sum() > 0.85 * np.isfinite(z).sum()
        assert np.mean(np.abs(f.depth()[both] - z[both]) <= 0.0001) > 0.99


def test_wrong_extrinsics_are_visible(capture, tmp_path: Path) -> None:
    """The pixel check above can fail: extrinsics of the opposite sign put the board's edges ~17 px off."""
    wrong = read_all(f"bag:{write_viewer_bag(tmp_path / 'wrong.bag', capture, color_tf_x=-DEPTH_SHIFT_M, noise_free=True)}")
    assert aligned_share(wrong, capture)[0] < 0.98


@pytest.mark.parametrize("layout", ["realsense-ros", "depthai-ros"])
def test_unregistered_with_tf_static(capture, replay_errors, tmp_path: Path, layout: str) -> None:
    bag = write_ros_bag(tmp_path / "unreg", capture, "mcap", layout, registered=False)
    frames = read_all(f"bag:{bag}")
    assert frames[0].meta["extrinsics"] == "/tf_static" and not frames[0].meta["registered_in_bag"]
    errs = abs_errors(zip(frames, capture.frames))
    assert np.mean(errs) <= np.mean(replay_errors) + 0.01, (errs, replay_errors)
    good, covered = aligned_share(read_all(f"bag:{write_ros_bag(tmp_path / 'exact', capture, 'mcap', layout, registered=False, noise_free=True)}"), capture)
    assert good > 0.99 and covered > 0.97, (good, covered)


def test_unknown_layout_lists_topics(tmp_path: Path, capture) -> None:
    out = BagOut(tmp_path / "other", "mcap")
    img = capture.frames[0].image
    out.write("/front/left/image", T0, image_msg(out.ts, False, T0, "left", img, "bgr8"))
    out.close()
    with pytest.raises(BagLayoutError, match=r"(?s)no known layout.*/front/left/image"):
        open_source(f"bag:{tmp_path / 'other'}")
    with pytest.raises(BagLayoutError, match="not an image topic"):
        open_source(f"bag:{tmp_path / 'other'}?depth=/nope&color=/front/left/image")
    with pytest.raises(SourceError, match="unknown bag option"):
        make_source(f"bag:{tmp_path / 'other'}?colour=/x")
    with pytest.raises(BagError, match="does not exist"):
        open_source(f"bag:{tmp_path / 'missing.bag'}")
    (tmp_path / "junk.bag").write_bytes(b"not a bag")
    with pytest.raises(BagError, match="cannot be opened"):
        open_source(f"bag:{tmp_path / 'junk.bag'}")


def test_explicit_topics(capture, tmp_path: Path) -> None:
    out = BagOut(tmp_path / "custom", "sqlite3")
    ts = out.ts
    cam = capture.frames[0].camera
    for k, f in enumerate(capture.frames[:2]):
        t = T0 + k * PERIOD
        out.write("/cam/info", t, info_msg(ts, False, t, "cam", cam))
        out.write("/cam/rgb", t, image_msg(ts, False, t, "cam", f.image, "bgr8"))
        out.write("/cam/z", t, image_msg(ts, False, t, "cam", depth_array(capture.depth_reg_m[k], "32FC1"), "32FC1"))
        png = np.frombuffer(cv2.imencode(".png", f.image)[1].tobytes(), np.uint8)
        out.write("/cam/rgb/compressed", t, ts.types["sensor_msgs/msg/CompressedImage"](header=_header(ts, False, t, "cam"), format="png", data=png))
    out.close()
    spec = f"bag:{tmp_path / 'custom'}?depth=/cam/z&color=/cam/rgb&color_info=/cam/info&depth_info=/cam/info&baseline=0.1"
    frames = read_all(spec)
    assert len(frames) == 2 and frames[0].meta["layout"] == "topics" and frames[0].baseline_m == 0.1
    ok = np.isfinite(capture.depth_reg_m[1])
    assert np.allclose(frames[1].depth()[ok], capture.depth_reg_m[1][ok], rtol=1e-5)
    compressed = read_all(spec.replace("color=/cam/rgb", "color=/cam/rgb/compressed"))
    assert [np.array_equal(f.image, c.image) for f, c in zip(compressed, capture.frames)] == [True, True]
