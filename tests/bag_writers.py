"""Simulated frames written as ROS bags (rosbags' writers): the RealSense Viewer, realsense-ros and
depthai-ros layouts, and tiny timed bags for playback tests. Shared by tests/device/test_bag_*.py."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

import cv2

from device import open_source
from device.formats.recording import EndOfRecording
from device.sources.bag import Rigid
from measure import MeasureOptions, PinholeCamera, measure_distance
from sim.scenario import make_model, simulate_frame
from sim.scenes import SceneParams, get_view
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


@functools.cache
def make_capture() -> Capture:
    """The simulated frames (seeded: the same every call, built once per test run)."""
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


def info_msg(ts, ros1: bool, t_ns: int, frame_id: str, cam: PinholeCamera, d=None, model: str = "plumb_bob"):
    """A CameraInfo of ``cam``; ``d`` the distortion coefficients of ``model`` (default: none, 5 zeros)."""
    K = np.array([cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1], float)
    P = np.array([cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0], float)
    D = np.zeros(5) if d is None else np.asarray(d, float)
    fields = dict(D=D, K=K, R=np.eye(3).ravel(), P=P) if ros1 else dict(d=D, k=K, r=np.eye(3).ravel(), p=P)
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, ros1, t_ns, frame_id), height=cam.height, width=cam.width, distortion_model=model,
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

    def write(self, topic: str, t_ns: int, msg, *, cut: bool = False) -> None:
        """Write ``msg``; ``cut``: only the first half of its serialized bytes (a damaged message)."""
        if topic not in self.conns:
            self.conns[topic] = self.w.add_connection(topic, msg.__msgtype__, typestore=self.ts)
        data = self.ts.serialize_ros1(msg, msg.__msgtype__) if self.ros1 else self.ts.serialize_cdr(msg, msg.__msgtype__)
        self.w.write(self.conns[topic], t_ns, data[: len(data) // 2] if cut else data)

    def close(self) -> None:
        self.w.close()


TINY_CAM = PinholeCamera(fx=50.0, fy=50.0, cx=15.5, cy=11.5, width=32, height=24)


def write_timed_bag(path: Path, kind: str, times_ns, stamps_ns=None, no_depth=(), cut=(), short=()) -> Path:
    """depthai-ros topics with tiny frames: colour message k (every pixel k % 256) and its registered depth
    (2 m) recorded at ``times_ns[k]`` and stamped ``stamps_ns[k]`` (default: the record time), written in
    the order given; the colour messages numbered in ``no_depth`` have no depth, those in ``cut`` a depth
    message cut to half its bytes, those in ``short`` a depth image holding half the pixels it claims."""
    out = BagOut(path, kind)
    out.write("/oak/rgb/camera_info", T0, info_msg(out.ts, out.ros1, T0, "rgb", TINY_CAM))
    out.write("/oak/stereo/camera_info", T0, info_msg(out.ts, out.ros1, T0, "rgb", TINY_CAM))
    z = np.full((TINY_CAM.height, TINY_CAM.width), 2000, np.uint16)
    for k, (t, st) in enumerate(zip(times_ns, times_ns if stamps_ns is None else stamps_ns)):
        img = np.full((TINY_CAM.height, TINY_CAM.width, 3), k % 256, np.uint8)
        out.write("/oak/rgb/image_raw", int(t), image_msg(out.ts, out.ros1, int(st), "rgb", img, "bgr8"))
        if k not in no_depth:
            msg = image_msg(out.ts, out.ros1, int(st), "rgb", z, "16UC1")
            if k in short:
                msg.data = msg.data[: msg.data.size // 2]
            out.write("/oak/stereo/image_raw", int(t), msg, cut=k in cut)
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


def read_all(spec: str) -> list:
    with open_source(spec) as src:
        frames = [src.read() for _ in range(len(src))]
        with pytest.raises(EndOfRecording):
            src.read()
    return frames


# depthai-ros publishes the colour camera's distortion as "rational_polynomial" with 8 coefficients (OpenCV's
# order: k1 k2 p1 p2 k3 k4 k5 k6); these are of a 70-degree lens.
OAK_RATIONAL = (-0.28, 0.09, 0.0006, -0.0004, -0.012, 0.02, 0.0, 0.0)
MARK_BGR = (255, 0, 255)  # magenta dots on the poster's measured end points, for a "user" to click


@functools.cache
def make_near_frame():
    """One simulated poster frame at 1.2 m (end points far enough out for distortion to matter), with a
    5x5 magenta dot drawn on each true end point of the poster width."""
    params = SceneParams("poster", distance_m=1.2, width=W, height=H, standoff_m=1.0)
    f, _ = simulate_frame(params, make_model("indoor", contention=0.3), np.random.default_rng([9, 0]), timestamp=T0 / 1e9)
    image = f.image.copy()
    for u, v in (f.meta["truth"].p1_px, f.meta["truth"].p2_px):
        image[int(round(v)) - 2:int(round(v)) + 3, int(round(u)) - 2:int(round(u)) + 3] = MARK_BGR
    return f, image


@functools.lru_cache(maxsize=8)
def _distort_maps(cam: PinholeCamera, coeffs: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Per distorted pixel of ``cam``, where its undistorted position falls in the pinhole image (x and
    y maps, float32): the forward model inverted by fixed-point iteration until it moves by under
    1e-12 (normalised units), at most 100 rounds. Made once per camera and lens: a bag's image and its
    depth use the same maps."""
    k1, k2, p1, p2, k3, k4, k5, k6 = (list(coeffs) + [0.0] * 8)[:8]
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    xd, yd = (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy
    x, y = xd.copy(), yd.copy()
    for _ in range(100):
        r2 = x * x + y * y
        radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
        nx = (xd - (2 * p1 * x * y + p2 * (r2 + 2 * x * x))) / radial
        ny = (yd - (p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)) / radial
        moved = max(float(np.abs(nx - x).max()), float(np.abs(ny - y).max()))
        x, y = nx, ny
        if moved < 1e-12:
            break
    return (x * cam.fx + cam.cx).astype(np.float32), (y * cam.fy + cam.cy).astype(np.float32)


def distort(image: np.ndarray, cam: PinholeCamera, coeffs, *, nearest: bool) -> np.ndarray:
    """What a lens with ``coeffs`` (OpenCV model) shows of a pinhole ``image`` of ``cam``: each distorted
    pixel samples the pinhole image where its undistorted position falls."""
    mx, my = _distort_maps(cam, tuple(coeffs))
    if nearest:
        return cv2.remap(image.astype(np.float32), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def write_distorted_oak_bag(path: Path, coeffs=OAK_RATIONAL, model: str = "rational_polynomial") -> Path:
    """depthai-ros topics (ROS 2, MCAP) holding :func:`make_near_frame` as an OAK records it: the colour
    image distorted by the lens ``coeffs``, depth registered to that distorted image, both camera_info
    with the same K and the distortion (``model``)."""
    f, marked = make_near_frame()
    cam = f.camera
    out = BagOut(path, "mcap")
    ts, fc = out.ts, "oak_rgb_camera_optical_frame"
    image = distort(marked, cam, coeffs, nearest=False)
    z = distort(f.depth(), cam, coeffs, nearest=True)
    out.write("/oak/rgb/camera_info", T0, info_msg(ts, False, T0, fc, cam, coeffs, model))
    out.write("/oak/rgb/image_raw", T0, image_msg(ts, False, T0, fc, image, "bgr8"))
    out.write("/oak/stereo/camera_info", T0, info_msg(ts, False, T0, fc, cam, coeffs, model))
    out.write("/oak/stereo/image_raw", T0 + 25_000_000, image_msg(ts, False, T0, fc, depth_array(z, "16UC1"), "16UC1"))
    out.close()
    return path


# A librealsense colour stream's "Inverse Brown Conrady" (k1 k2 p1 p2 k3: distorted -> undistorted).
RS_INVERSE = (0.3, -0.1, 0.0008, -0.0005, 0.02)


def distort_inverse_brown_conrady(image: np.ndarray, cam: PinholeCamera, coeffs) -> np.ndarray:
    """What a colour sensor with librealsense's inverse model shows of a pinhole ``image``: the model
    gives each distorted pixel's undistorted position in closed form (``rs2_deproject_pixel_to_point``)."""
    k1, k2, p1, p2, k3 = coeffs
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    x, y = (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy
    r2 = x * x + y * y
    f = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    ux = x * f + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    uy = y * f + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    mx, my = (ux * cam.fx + cam.cx).astype(np.float32), (uy * cam.fy + cam.cy).astype(np.float32)
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def write_distorted_viewer_bag(path: Path, coeffs=RS_INVERSE) -> Path:
    """The RealSense Viewer's layout holding :func:`make_near_frame`: rgb8 colour distorted by librealsense's
    inverse model (camera_info "Inverse Brown Conrady"), Z16 depth from a rectified depth stream ("Brown
    Conrady", zero coefficients) at the colour camera's pose and K (tf identity)."""
    f, marked = make_near_frame()
    cam = f.camera
    out = BagOut(path, "ros1")
    ts = out.ts
    d, c = "/device_0/sensor_0/Depth_0", "/device_0/sensor_1/Color_0"
    out.write("/device_0/sensor_0/option/Depth Units/value", T0, ts.types["std_msgs/msg/Float32"](data=0.0001))
    out.write(f"{d}/info/camera_info", T0, info_msg(ts, True, 0, "", cam, np.zeros(5), "Brown Conrady"))
    out.write(f"{c}/info/camera_info", T0, info_msg(ts, True, 0, "", cam, coeffs, "Inverse Brown Conrady"))
    out.write(f"{d}/tf/0", T0, transform_msg(ts, Rigid()))
    out.write(f"{c}/tf/0", T0, transform_msg(ts, Rigid()))
    t = T0 + 1_000_000
    image = distort_inverse_brown_conrady(marked, cam, coeffs)
    out.write(f"{c}/image/data", t, image_msg(ts, True, t, "", image[:, :, ::-1], "rgb8"))
    out.write(f"{d}/image/data", t + 2_000_000, image_msg(ts, True, t + 2_000_000, "", depth_array(f.depth(), "mono16", 0.0001), "mono16"))
    out.close()
    return path


def find_marks(image: np.ndarray) -> list[tuple[float, float]]:
    """The centres (px) of the magenta dots seen in ``image``, left to right: where a user clicks."""
    diff = np.abs(image.astype(np.int32) - np.array(MARK_BGR)).max(axis=2)
    n, _, stats, centres = cv2.connectedComponentsWithStats((diff < 90).astype(np.uint8))
    blobs = [tuple(centres[i]) for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= 4]
    return sorted(blobs)
