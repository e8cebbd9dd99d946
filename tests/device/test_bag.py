"""`bag:PATH`: ROS 1 bags, ROS 2 bags (MCAP, sqlite3) in the RealSense Viewer, realsense-ros and depthai-ros
layouts, written here with rosbags' writers from simulated frames and measured against the simulator's truth."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from device import SourceError, SourceTimeout, make_source, open_source
from device.sources.bag import (
    BagError,
    BagLayoutError,
    BagReader,
    Rigid,
    align_depth_to_color,
    pair_by_time,
    summarize_bag,
)
from device.formats.recording import EndOfRecording, RecordingWriter
from device.base import SourceInfo
from factories import FakeClock
from measure import MeasureOptions, PinholeCamera, measure_distance
from sim.raycast import Pose, cast
from sim.scenario import make_model, simulate_frame
from sim.scenes import SceneParams, build_scene, get_view
from sim.sensor import sense

W, H = 640, 360
PARAMS = SceneParams("poster", distance_m=3.0, width=W, height=H, standoff_m=1.0)
N_FRAMES = 3
T0 = 1_700_000_000 * 10**9
PERIOD = 33_333_333
DEPTH_SHIFT_M = -0.05  # the unregistered depth camera sits 5 cm left of the colour camera


@dataclass
class Capture:
    """Simulated frames and what a depth camera would have recorded of them."""

    frames: list  # registered Frames (the simulator's colour camera), meta["truth"]
    depth_reg_m: list  # the frames' depth (m, colour camera)
    depth_cam: PinholeCamera  # the unregistered depth camera (half resolution, 5 cm to the left)
    depth_unreg_m: list  # depth seen by that camera (m)
    depth_unreg_true: np.ndarray  # that camera's noise-free depth (m), for pixel-level checks of the alignment


@pytest.fixture(scope="module")
def capture() -> Capture:
    model = make_model("indoor", contention=0.3)
    frames, reg, unreg = [], [], []
    view_d = get_view(PARAMS, shift_m=DEPTH_SHIFT_M)
    for k in range(N_FRAMES):
        f, _ = simulate_frame(PARAMS, model, np.random.default_rng([7, k]), timestamp=(T0 + k * PERIOD) / 1e9)
        frames.append(f)
        reg.append(f.depth())
        out = sense(view_d, model, np.random.default_rng([8, k]))
        with np.errstate(divide="ignore", invalid="ignore"):
            z = view_d.camera.fx * model.baseline_wide_m / out.disparity.astype(np.float64)
        z[~(out.disparity > 0)] = np.nan
        unreg.append(z[::2, ::2])  # a half-resolution depth camera: pixel k is pixel 2k of the full one
    c = view_d.camera
    depth_cam = PinholeCamera(fx=c.fx / 2, fy=c.fy / 2, cx=c.cx / 2, cy=c.cy / 2, width=W // 2, height=H // 2)
    return Capture(frames, reg, depth_cam, unreg, np.array(view_d.depth[::2, ::2]))


# ---------------------------------------------------------------------------------------------
# writing bags


def _stamp(ts, t_ns: int):
    return ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def _header(ts, ros1: bool, t_ns: int, frame_id: str):
    Header = ts.types["std_msgs/msg/Header"]
    return Header(seq=0, stamp=_stamp(ts, t_ns), frame_id=frame_id) if ros1 else Header(stamp=_stamp(ts, t_ns), frame_id=frame_id)


def image_msg(ts, ros1: bool, t_ns: int, frame_id: str, array: np.ndarray, encoding: str):
    a = np.ascontiguousarray(array)
    h, w = a.shape[:2]
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, ros1, t_ns, frame_id), height=h, width=w, encoding=encoding, is_bigendian=0,
        step=a.strides[0], data=np.frombuffer(a.tobytes(), np.uint8),
    )


def depth_array(z_m: np.ndarray, encoding: str, unit_m: float = 0.001) -> np.ndarray:
    if encoding == "32FC1":
        return np.where(np.isfinite(z_m), z_m, np.nan).astype(np.float32)
    code = np.rint(np.nan_to_num(z_m) / unit_m)
    return np.where(np.isfinite(z_m) & (code <= 65535), code, 0).astype(np.uint16)


def info_msg(ts, ros1: bool, t_ns: int, frame_id: str, cam: PinholeCamera):
    K = np.array([cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1], float)
    P = np.array([cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0], float)
    fields = dict(D=np.zeros(5), K=K, R=np.eye(3).ravel(), P=P) if ros1 else dict(d=np.zeros(5), k=K, r=np.eye(3).ravel(), p=P)
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, ros1, t_ns, frame_id), height=cam.height, width=cam.width, distortion_model="plumb_bob",
        binning_x=0, binning_y=0, roi=roi, **fields,
    )


def transform_msg(ts, T: Rigid):
    R = T.rotation
    w = np.sqrt(max(1.0 + R[0, 0] + R[1, 1] + R[2, 2], 1e-12)) / 2
    q = ts.types["geometry_msgs/msg/Quaternion"](x=(R[2, 1] - R[1, 2]) / (4 * w), y=(R[0, 2] - R[2, 0]) / (4 * w), z=(R[1, 0] - R[0, 1]) / (4 * w), w=w)
    v = ts.types["geometry_msgs/msg/Vector3"](x=T.t[0], y=T.t[1], z=T.t[2])
    return ts.types["geometry_msgs/msg/Transform"](translation=v, rotation=q)


class BagOut:
    """One writer interface over rosbags' ROS 1 and ROS 2 writers."""

    def __init__(self, path: Path, kind: str) -> None:
        self.ros1 = kind == "ros1"
        self.ts = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if self.ros1:
            self.w = Writer1(path)
        else:
            self.w = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
        self.w.open()
        self.conns: dict[str, object] = {}

    def write(self, topic: str, t_ns: int, msg) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.w.add_connection(topic, msg.__msgtype__, typestore=self.ts)
        data = self.ts.serialize_ros1(msg, msg.__msgtype__) if self.ros1 else self.ts.serialize_cdr(msg, msg.__msgtype__)
        self.w.write(self.conns[topic], t_ns, data)

    def close(self) -> None:
        self.w.close()


TINY_CAM = PinholeCamera(fx=50.0, fy=50.0, cx=15.5, cy=11.5, width=32, height=24)


def write_timed_bag(path: Path, kind: str, times_ns, stamps_ns=None, no_depth=()) -> Path:
    """depthai-ros topics with tiny frames: colour message k (every pixel k % 256) and its registered depth
    (2 m) recorded at ``times_ns[k]`` and stamped ``stamps_ns[k]`` (default: the record time), written in
    the order given; the colour messages numbered in ``no_depth`` have no depth."""
    out = BagOut(path, kind)
    out.write("/oak/rgb/camera_info", T0, info_msg(out.ts, out.ros1, T0, "rgb", TINY_CAM))
    out.write("/oak/stereo/camera_info", T0, info_msg(out.ts, out.ros1, T0, "rgb", TINY_CAM))
    z = np.full((TINY_CAM.height, TINY_CAM.width), 2000, np.uint16)
    for k, (t, st) in enumerate(zip(times_ns, times_ns if stamps_ns is None else stamps_ns)):
        img = np.full((TINY_CAM.height, TINY_CAM.width, 3), k % 256, np.uint8)
        out.write("/oak/rgb/image_raw", int(t), image_msg(out.ts, out.ros1, int(st), "rgb", img, "bgr8"))
        if k not in no_depth:
            out.write("/oak/stereo/image_raw", int(t), image_msg(out.ts, out.ros1, int(st), "rgb", z, "16UC1"))
    out.close()
    return path


def write_viewer_bag(path: Path, cap: Capture, *, depth_delay_ns: int = 2_000_000, color_tf_x: float = DEPTH_SHIFT_M,
                     noise_free: bool = False, depth: tuple[PinholeCamera, list] | None = None) -> Path:
    """The RealSense Viewer's layout: raw (unregistered) Z16 depth in depth units of 0.1 mm, rgb8 colour,
    their camera_info, tf/0 extrinsics (depth is the reference), Depth Units and Stereo Baseline options."""
    out = BagOut(path, "ros1")
    ts = out.ts
    f32 = ts.types["std_msgs/msg/Float32"]
    d, c = "/device_0/sensor_0/Depth_0", "/device_0/sensor_1/Color_0"
    out.write("/device_0/sensor_0/option/Depth Units/value", T0, f32(data=0.0001))
    out.write("/device_0/sensor_0/option/Stereo Baseline/value", T0, f32(data=50.0))
    out.write(f"{d}/info/camera_info", T0, info_msg(ts, True, 0, "", depth[0] if depth else cap.depth_cam))
    out.write(f"{c}/info/camera_info", T0, info_msg(ts, True, 0, "", cap.frames[0].camera))
    out.write(f"{d}/tf/0", T0, transform_msg(ts, Rigid()))
    out.write(f"{c}/tf/0", T0, transform_msg(ts, Rigid(t=(color_tf_x, 0.0, 0.0))))  # p_color = p_depth - (5 cm, 0, 0)
    for k, f in enumerate(cap.frames):
        t = T0 + 1_000_000 + k * PERIOD
        out.write(f"{c}/image/data", t, image_msg(ts, True, t, "", f.image[:, :, ::-1], "rgb8"))
        td = t + depth_delay_ns
        z = depth[1][k] if depth else cap.depth_unreg_true if noise_free else cap.depth_unreg_m[k]
        out.write(f"{d}/image/data", td, image_msg(ts, True, td, "", depth_array(z, "mono16", 0.0001), "mono16"))
    out.close()
    return path


def write_ros_bag(path: Path, cap: Capture, kind: str, layout: str, *, encoding: str = "16UC1", registered: bool = True,
                  noise_free: bool = False) -> Path:
    """realsense-ros (``/camera/camera/...``) or depthai-ros (``/oak/...``) topics in a ROS 2 bag; unregistered
    depth comes with /tf_static between the optical frames (through a base frame, as the drivers publish it)."""
    out = BagOut(path, kind)
    ts = out.ts
    if layout == "realsense-ros":
        color, depth = "/camera/camera/color", "/camera/camera/aligned_depth_to_color" if registered else "/camera/camera/depth"
        depth_image = depth + ("/image_raw" if registered else "/image_rect_raw")
        fc, fd, base = "camera_color_optical_frame", "camera_color_optical_frame" if registered else "camera_depth_optical_frame", "camera_link"
    else:
        color, depth, depth_image = "/oak/rgb", "/oak/stereo", "/oak/stereo/image_raw"
        fc, fd, base = "oak_rgb_camera_optical_frame", "oak_rgb_camera_optical_frame" if registered else "oak_right_camera_optical_frame", "oak-d-base-frame"
    cam = cap.frames[0].camera
    if not registered:
        TS, TFM = ts.types["geometry_msgs/msg/TransformStamped"], ts.types["tf2_msgs/msg/TFMessage"]
        # base -> colour: colour 2 cm right of base, rotated about y by 0; base -> depth: 3 cm left of base.
        edges = [(base, fc, Rigid(t=(0.02, 0.0, 0.0))), (base, fd, Rigid(t=(0.02 + DEPTH_SHIFT_M, 0.0, 0.0)))]
        msg = TFM(transforms=[TS(header=_header(ts, False, T0, p), child_frame_id=ch, transform=transform_msg(ts, T)) for p, ch, T in edges])
        out.write("/tf_static", T0, msg)
    dcam = cam if registered else cap.depth_cam
    for k, f in enumerate(cap.frames):
        t = T0 + k * PERIOD
        out.write(f"{color}/camera_info", t, info_msg(ts, False, t, fc, cam))
        out.write(f"{color}/image_raw", t, image_msg(ts, False, t, fc, f.image, "bgr8"))
        z = cap.depth_reg_m[k] if registered else cap.depth_unreg_true if noise_free else cap.depth_unreg_m[k]
        out.write(f"{depth}/camera_info", t + 7_000_000, info_msg(ts, False, t, fd, dcam))
        # Registered depth arrives 25 ms after its colour (alignment takes time) but carries the colour's stamp.
        out.write(depth_image, t + 25_000_000, image_msg(ts, False, t, fd, depth_array(z, encoding), encoding))
    out.close()
    return path


# ---------------------------------------------------------------------------------------------
# measuring


def abs_errors(frames) -> np.ndarray:
    errs = []
    for f, ref in frames:
        truth = ref.meta["truth"]
        m = measure_distance(f, truth.p1_px, truth.p2_px, MeasureOptions(method="robust"))
        errs.append(abs(m.distance_m - truth.length_m))
    return np.array(errs)


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


def read_all(spec: str) -> list:
    with open_source(spec) as src:
        frames = [src.read() for _ in range(len(src))]
        with pytest.raises(EndOfRecording):
            src.read()
    return frames


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


def test_random_access_and_start(capture, tmp_path: Path) -> None:
    bag = write_ros_bag(tmp_path / "rs", capture, "mcap", "realsense-ros")
    with open_source(f"bag:{bag}?start=2") as src:
        assert len(src) == N_FRAMES and src.read().meta["frame_index"] == 2
        f1 = src.frame(1)
        assert np.array_equal(f1.image, capture.frames[1].image)
        src.seek(0)
        assert src.read().meta["frame_index"] == 0
    with open_source(f"bag:{bag}?loop=1") as src:
        assert [src.read().meta["frame_index"] for _ in range(N_FRAMES + 1)] == [0, 1, 2, 0]


def test_open_reads_only_the_index(capture, tmp_path: Path, monkeypatch) -> None:
    """By construction: opening deserialises no image message, whatever the bag's size."""
    from rosbags.highlevel import AnyReader

    seen: list[str] = []
    original = AnyReader.deserialize

    def spy(self, raw, typ):
        seen.append(typ)
        return original(self, raw, typ)

    monkeypatch.setattr(AnyReader, "deserialize", spy)
    for bag in (write_viewer_bag(tmp_path / "v.bag", capture), write_ros_bag(tmp_path / "m", capture, "mcap", "depthai-ros"),
                write_ros_bag(tmp_path / "s", capture, "sqlite3", "realsense-ros")):
        seen.clear()
        with BagReader(bag) as br:
            assert len(br.contents) == N_FRAMES and br.contents.indexed
            assert seen.count("sensor_msgs/msg/Image") <= 7  # 3 per topic for the latency, 1 for the depth encoding
            seen.clear()
            br.frame(N_FRAMES - 1)
            assert seen.count("sensor_msgs/msg/Image") == 2


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


def test_summary_and_replay_command(capture, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cli.main import app

    bag = write_viewer_bag(tmp_path / "viewer.bag", capture)
    s = summarize_bag(bag)
    assert (s["layout"], s["storage"], s["frames"], s["registered"]) == ("realsense-viewer", "ROS 1 bag", N_FRAMES, False)
    assert s["depth_unit_m"] == pytest.approx(0.0001) and s["skew_ms"]["max"] == pytest.approx(2.0)
    res = CliRunner().invoke(app, ["replay", str(bag)])
    assert res.exit_code == 0, res.output
    assert "realsense-viewer" in res.output and "/device_0/sensor_0/Depth_0/image/data" in res.output
    res = CliRunner().invoke(app, ["replay", str(bag), "--json"])
    assert json.loads(res.output)["frames"] == N_FRAMES
    # realsense-ros: registered depth recorded 25 ms after its colour pairs with it by stamp, not with the next colour
    ros = write_ros_bag(tmp_path / "rs", capture, "mcap", "realsense-ros")
    s = summarize_bag(ros)
    assert s["frames"] == N_FRAMES and s["latency_ms"]["depth"] - s["latency_ms"]["color"] == pytest.approx(25.0)
    assert s["skew_ms"]["max"] == pytest.approx(0.0, abs=1e-6)
    res = CliRunner().invoke(app, ["replay", str(ros)])
    assert res.exit_code == 0 and "25.0 ms after colour" in res.output, res.output


@pytest.mark.parametrize("options", ["", "?realtime=1"])
def test_measure_command_on_a_bag(capture, tmp_path: Path, clock: FakeClock, options: str) -> None:
    """`measure --frame 2` reads frame 2 directly: realtime=1 makes it wait for no frame before it."""
    from typer.testing import CliRunner

    from cli.main import app

    bag = write_ros_bag(tmp_path / "rs", capture, "mcap", "realsense-ros")
    truth = capture.frames[2].meta["truth"]
    p1, p2 = (f"{x:g},{y:g}" for x, y in (truth.p1_px, truth.p2_px))
    res = CliRunner().invoke(app, ["measure", f"bag:{bag}{options}", "--p1", p1, "--p2", p2, "--frame", "2", "--json"])
    assert res.exit_code == 0, res.output
    assert abs(json.loads(res.output)["distance_m"] - truth.length_m) < 0.02
    assert clock.sleeps == []  # reading frames 0-2 in turn would have slept 2 x 33 ms


# ---------------------------------------------------------------------------------------------
# realtime playback: device/pacing.py's Pacer on a fake clock (no wall-clock time)

MS = 1_000_000
PACED_MS = (0, 125, 250, 750, 875)  # 125 ms apart with one 500 ms gap (binary fractions: exact due times)


@pytest.fixture
def clock(monkeypatch) -> FakeClock:
    import device.pacing as pacing

    fake = FakeClock()
    monkeypatch.setattr(pacing, "time", fake)
    return fake


def play(src, clock: FakeClock, n: int, timeout_s: float = 1.0) -> list[tuple[int, float]]:
    """Read ``n`` frames: each one's number (its pixel value) and when it came (s after the first read)."""
    t0, out = clock.now, []
    for _ in range(n):
        f = src.read(timeout_s)
        out.append((int(f.image[0, 0, 0]), clock.now - t0))
    return out


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_realtime_paces_on_record_times(clock: FakeClock, tmp_path: Path, kind: str) -> None:
    """realtime=1 waits out each gap between the frames' record times, the 500 ms one too; the header
    stamps (here 1/30 s apart) are what the frames carry, not what sets the pace."""
    stamps = [T0 + k * PERIOD for k in range(5)]
    bag = write_timed_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind, [T0 + t * MS for t in PACED_MS], stamps)
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert [src.frame(k).timestamp for k in range(5)] == [t / 1e9 for t in stamps]
        assert clock.sleeps == []  # frame(k) waits for nothing
        assert play(src, clock, 5) == [(0, 0.0), (1, 0.125), (2, 0.25), (3, 0.75), (4, 0.875)]
    assert clock.sleeps == [0.125, 0.125, 0.5, 0.125]


def test_realtime_speed_start_loop_and_off(clock: FakeClock, tmp_path: Path) -> None:
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS])
    with open_source(f"bag:{bag}?realtime=1&speed=2") as src:
        assert play(src, clock, 5) == [(0, 0.0), (1, 0.0625), (2, 0.125), (3, 0.375), (4, 0.4375)]
    # start=3: frame 3 is due at once; at the end the loop starts again with frame 0 due at once
    with open_source(f"bag:{bag}?realtime=1&loop=1&start=3") as src:
        assert play(src, clock, 6) == [(3, 0.0), (4, 0.125), (0, 0.125), (1, 0.25), (2, 0.375), (3, 0.875)]
    clock.sleeps.clear()
    with open_source(f"bag:{bag}?loop=1") as src:
        assert play(src, clock, 7) == [(k % 5, 0.0) for k in range(7)]
    assert clock.sleeps == []
    with pytest.raises(SourceError, match="speed=0.0 must be a positive number"):
        open_source(f"bag:{bag}?realtime=1&speed=0")


def test_realtime_gap_past_the_timeout_times_out_then_plays_on(clock: FakeClock, tmp_path: Path) -> None:
    """A frame due after the read's timeout raises SourceTimeout after that timeout, as a live camera
    with no frame would, and is the next frame read: no frame skipped, the pace kept."""
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS])
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert play(src, clock, 3) == [(0, 0.0), (1, 0.125), (2, 0.25)]
        with pytest.raises(SourceTimeout, match="due in 0.50 s, after the 0.25 s timeout"):
            src.read(timeout_s=0.25)
        assert play(src, clock, 2) == [(3, 0.25), (4, 0.375)]
    assert clock.sleeps == [0.125, 0.125, 0.25, 0.25, 0.125]


def test_realtime_seek_and_slow_reader(clock: FakeClock, tmp_path: Path) -> None:
    """seek(k) makes frame k due at once; a reader slower than the bag gets the frames already due without
    a wait, and the pace holds to the record times (frame k at PACED_MS[k] after the start), not drifting."""
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS])
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert play(src, clock, 1) == [(0, 0.0)]
        src.seek(3)
        assert play(src, clock, 2) == [(3, 0.0), (4, 0.125)]
        src.seek(0)
        t0 = clock.now
        src.read()
        clock.now += 0.375  # processing frame 0 took 0.375 s: frames 1 and 2 are late, frame 3 is due at 0.75
        assert play(src, clock, 3) == [(1, 0.0), (2, 0.0), (3, 0.375)]
        assert clock.now - t0 == 0.75


def test_realtime_unpaired_colour_message_keeps_its_neighbours_times(clock: FakeClock, tmp_path: Path) -> None:
    """Colour message 2 has no depth, so it is no frame: frame 2 is message 3, due at message 3's time."""
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS], no_depth=(2,))
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert len(src) == 4
        assert play(src, clock, 4) == [(0, 0.0), (1, 0.125), (3, 0.75), (4, 0.875)]


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_realtime_record_times_out_of_order_or_repeated(clock: FakeClock, tmp_path: Path, kind: str) -> None:
    """Messages written out of record-time order play in record-time order; two frames with one record time
    come together; header stamps going backwards change nothing. No wait is negative (FakeClock refuses
    one, as time.sleep does) and none is added."""
    rec_ms = (0, 125, 500, 250, 250, 625)  # message 2 recorded after 3 and 4 but written before them
    stamp_ms = (0, 100, 50, 300, 300, 10)  # stamps going back twice
    bag = write_timed_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind,
                          [T0 + t * MS for t in rec_ms], [T0 + t * MS for t in stamp_ms])
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert play(src, clock, 6) == [(0, 0.0), (1, 0.125), (3, 0.25), (4, 0.25), (2, 0.5), (5, 0.625)]
    assert clock.sleeps == [0.125, 0.125, 0.25, 0.125]


def test_open_time_many_messages(tmp_path: Path) -> None:
    """A bag of 6000 small image messages opens without reading them (timed for information, not asserted)."""
    write_timed_bag(tmp_path / "many", "mcap", T0 + np.arange(3000) * PERIOD)
    t0 = time.perf_counter()
    with BagReader(tmp_path / "many") as br:
        assert len(br.contents) == 3000
        elapsed = time.perf_counter() - t0
        f = br.frame(2999)
    assert np.nanmedian(f.depth()) == pytest.approx(2.0)
    print(f"opened a 6000-message bag in {elapsed * 1000:.0f} ms")


def test_mcap_without_message_indexes_is_scanned(capture, tmp_path: Path) -> None:
    """An MCAP written without message indexes still opens (read through once) and says so."""
    from mcap.writer import IndexType, Writer

    ts = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "noindex.mcap"
    cam = capture.frames[0].camera
    with open(path, "wb") as fh:
        w = Writer(fh, index_types=IndexType.NONE)
        w.start(profile="ros2", library="test")
        channels = {}
        for topic, typ in (("/oak/rgb/camera_info", "sensor_msgs/msg/CameraInfo"), ("/oak/stereo/camera_info", "sensor_msgs/msg/CameraInfo"),
                           ("/oak/rgb/image_raw", "sensor_msgs/msg/Image"), ("/oak/stereo/image_raw", "sensor_msgs/msg/Image")):
            schema = w.register_schema(name=typ, encoding="ros2msg", data=ts.generate_msgdef(typ, ros_version=2)[0].encode())
            channels[topic] = w.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)
        for k, f in enumerate(capture.frames[:2]):
            t = T0 + k * PERIOD
            for topic, msg in (("/oak/rgb/camera_info", info_msg(ts, False, t, "rgb", cam)), ("/oak/stereo/camera_info", info_msg(ts, False, t, "rgb", cam)),
                               ("/oak/rgb/image_raw", image_msg(ts, False, t, "rgb", f.image, "bgr8")),
                               ("/oak/stereo/image_raw", image_msg(ts, False, t, "rgb", depth_array(capture.depth_reg_m[k], "16UC1"), "16UC1"))):
                w.add_message(channels[topic], log_time=t, publish_time=t, data=bytes(ts.serialize_cdr(msg, msg.__msgtype__)))
        w.finish()
    assert summarize_bag(path)["indexed"] is False
    frames = read_all(f"bag:{path}")
    assert len(frames) == 2 and np.array_equal(frames[1].image, capture.frames[1].image)


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


def test_service_serves_a_bag(capture, tmp_path: Path) -> None:
    """`depthruler serve --source bag:...`: the frames stream, the bag ends like a replay, and a click measures."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    bag = write_viewer_bag(tmp_path / "viewer.bag", capture)
    with TestClient(create_app(f"bag:{bag}", db_path=tmp_path / "h.db", capture_fps=200.0, reconnect_initial_s=0.02), base_url="http://127.0.0.1") as c:
        deadline = time.monotonic() + 20
        while c.get("/api/source").json()["state"] != "ended" and time.monotonic() < deadline:
            time.sleep(0.02)
        s = c.get("/api/source").json()
        assert s["state"] == "ended" and s["frames"] == N_FRAMES, s
        f = c.get("/api/frames/latest", params={"after": 0, "wait": 5}).json()
        truth = capture.frames[-1].meta["truth"]
        r = c.post("/api/measure", json={"frame_id": f["id"], "p1": list(truth.p1_px), "p2": list(truth.p2_px), "options": {}})
        assert r.status_code == 200, r.text
        assert abs(r.json()["distance_m"] - truth.length_m) < 0.02
