"""Bag replay against a plain rosbags read of the same messages, in one process.

Two bags are written into a temporary folder from one simulated 1280x720 poster frame (rosbags'
writers): a ROS 2 MCAP bag in realsense-ros's layout with depth registered to colour
(``aligned_depth_to_color``, 16UC1 mm, bgr8 colour), and a ROS 1 bag in the RealSense Viewer's layout
with unregistered depth (a 640x360 depth camera 5 cm to the left, Z16 in 0.1 mm units, rgb8 colour,
``tf/0`` extrinsics). For every frame, interleaved: the reference reads its colour and depth messages
from the bag's index and deserializes them (rosbags' ``AnyReader.messages`` + ``deserialize``, the
pixels viewed as an array), and ``BagReader.frame(i)`` makes the measurable frame (decode, undistort,
register, disparity). CPU time of this process per frame, median over the frames and repeats.
Targets: registered at most 1.5x the reference, unregistered Viewer depth at most 5x.

    python bench/bench_bag.py [--frames 20] [--repeats 3] [--write]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.results_file import machine, replace_section

SECTION = "## Bag replay"
T0 = 1_700_000_000 * 10**9
PERIOD = 33_333_333
TARGETS = {"registered": 1.5, "viewer": 5.0}


def _scene() -> tuple[np.ndarray, np.ndarray, object, np.ndarray, object]:
    """One simulated poster frame at 1280x720: colour, registered depth (m), the colour camera, and
    what a half-resolution depth camera 5 cm to the left sees (m) with that camera."""
    from measure import PinholeCamera
    from sim.scenario import make_model, simulate_frame
    from sim.scenes import SceneParams, get_view
    from sim.sensor import sense

    params = SceneParams("poster", distance_m=3.0, width=1280, height=720)
    model = make_model("indoor", contention=0.3)
    frame, _ = simulate_frame(params, model, np.random.default_rng(1))
    view = get_view(params, shift_m=-0.05)
    out = sense(view, model, np.random.default_rng(2))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = view.camera.fx * model.baseline_wide_m / out.disparity.astype(np.float64)
    z[~(out.disparity > 0)] = np.nan
    c = view.camera
    depth_cam = PinholeCamera(fx=c.fx / 2, fy=c.fy / 2, cx=c.cx / 2, cy=c.cy / 2, width=c.width // 2, height=c.height // 2)
    return frame.image, frame.depth(), frame.camera, z[::2, ::2], depth_cam


class _Out:
    """rosbags' ROS 1 or ROS 2 (MCAP) writer with a connection per topic."""

    def __init__(self, path: Path, ros1: bool) -> None:
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2
        from rosbags.typesys import Stores, get_typestore

        self.ros1 = ros1
        self.ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        self.w = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self.w.open()
        self.conns: dict[str, object] = {}

    def header(self, t_ns: int, frame_id: str):
        stamp = self.ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        Header = self.ts.types["std_msgs/msg/Header"]
        return Header(seq=0, stamp=stamp, frame_id=frame_id) if self.ros1 else Header(stamp=stamp, frame_id=frame_id)

    def image(self, t_ns: int, frame_id: str, a: np.ndarray, encoding: str):
        a = np.ascontiguousarray(a)
        return self.ts.types["sensor_msgs/msg/Image"](header=self.header(t_ns, frame_id), height=a.shape[0], width=a.shape[1],
                                                      encoding=encoding, is_bigendian=0, step=a.strides[0],
                                                      data=np.frombuffer(a.tobytes(), np.uint8))  # fmt: skip

    def info(self, t_ns: int, frame_id: str, cam):
        K = np.array([cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1], float)
        P = np.array([cam.fx, 0, cam.cx, 0, 0, cam.fy, cam.cy, 0, 0, 0, 1, 0], float)
        fields = dict(D=np.zeros(5), K=K, R=np.eye(3).ravel(), P=P) if self.ros1 else dict(d=np.zeros(5), k=K, r=np.eye(3).ravel(), p=P)
        roi = self.ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return self.ts.types["sensor_msgs/msg/CameraInfo"](header=self.header(t_ns, frame_id), height=cam.height, width=cam.width,
                                                           distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **fields)  # fmt: skip

    def transform(self, tx: float):
        v = self.ts.types["geometry_msgs/msg/Vector3"](x=tx, y=0.0, z=0.0)
        q = self.ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        return self.ts.types["geometry_msgs/msg/Transform"](translation=v, rotation=q)

    def write(self, topic: str, t_ns: int, msg) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.w.add_connection(topic, msg.__msgtype__, typestore=self.ts)
        data = self.ts.serialize_ros1(msg, msg.__msgtype__) if self.ros1 else self.ts.serialize_cdr(msg, msg.__msgtype__)
        self.w.write(self.conns[topic], t_ns, data)

    def close(self) -> None:
        self.w.close()


def _mm(z_m: np.ndarray, unit_m: float) -> np.ndarray:
    code = np.rint(np.nan_to_num(z_m) / unit_m)
    return np.where(np.isfinite(z_m) & (code <= 65535), code, 0).astype(np.uint16)


def write_bags(folder: Path, frames: int) -> dict[str, Path]:
    """The registered realsense-ros MCAP bag and the unregistered Viewer ROS 1 bag, ``frames`` each."""
    image, depth, cam, depth_unreg, depth_cam = _scene()
    ros2 = _Out(folder / "registered.mcap", ros1=False)
    color, aligned, frame_id = "/camera/camera/color", "/camera/camera/aligned_depth_to_color", "camera_color_optical_frame"
    for k in range(frames):
        t = T0 + k * PERIOD
        ros2.write(f"{color}/camera_info", t, ros2.info(t, frame_id, cam))
        ros2.write(f"{color}/image_raw", t, ros2.image(t, frame_id, image, "bgr8"))
        ros2.write(f"{aligned}/camera_info", t, ros2.info(t, frame_id, cam))
        ros2.write(f"{aligned}/image_raw", t + 25_000_000, ros2.image(t, frame_id, _mm(depth, 0.001), "16UC1"))
    ros2.close()
    ros1 = _Out(folder / "viewer.bag", ros1=True)
    f32 = ros1.ts.types["std_msgs/msg/Float32"]
    d, c = "/device_0/sensor_0/Depth_0", "/device_0/sensor_1/Color_0"
    ros1.write("/device_0/sensor_0/option/Depth Units/value", T0, f32(data=0.0001))
    ros1.write("/device_0/sensor_0/option/Stereo Baseline/value", T0, f32(data=50.0))
    ros1.write(f"{d}/info/camera_info", T0, ros1.info(0, "", depth_cam))
    ros1.write(f"{c}/info/camera_info", T0, ros1.info(0, "", cam))
    ros1.write(f"{d}/tf/0", T0, ros1.transform(0.0))
    ros1.write(f"{c}/tf/0", T0, ros1.transform(-0.05))
    for k in range(frames):
        t = T0 + 1_000_000 + k * PERIOD
        ros1.write(f"{c}/image/data", t, ros1.image(t, "", image[:, :, ::-1], "rgb8"))
        ros1.write(f"{d}/image/data", t + 2_000_000, ros1.image(t + 2_000_000, "", _mm(depth_unreg, 0.0001), "mono16"))
    ros1.close()
    return {"registered": folder / "registered.mcap", "viewer": folder / "viewer.bag"}


def _plain_read(reader, conns: dict[str, list], times: dict[str, np.ndarray], i: int) -> int:
    """The reference: frame ``i``'s colour and depth messages read by time and deserialized, their
    pixels viewed as arrays (what any reader of the bag pays); returns the pixel bytes."""
    n = 0
    for topic, t in ((k, int(v[i])) for k, v in times.items()):
        for conn, _, raw in reader.messages(connections=conns[topic], start=t, stop=t + 1):
            msg = reader.deserialize(raw, conn.msgtype)
            n += np.frombuffer(msg.data, np.uint8).size
    return n


def run(frames: int, repeats: int) -> dict[str, dict]:
    from device.sources.bag import BagReader
    from device.sources.bag.storage import topic_times

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kind, path in write_bags(Path(tmp), frames).items():
            with BagReader(path) as br:
                c = br.contents
                reader = br._reader  # the same opened bag: both sides read the same bytes through the same reader
                topics = (c.layout.color_topic, c.layout.depth_topic)
                conns = {t: [x for x in reader.connections if x.topic == t] for t in topics}
                times = {t: topic_times(conns[t])[0] for t in topics}
                br.frame(0)
                _plain_read(reader, conns, times, 0)  # warm-up: maps, typestores, caches
                ours, ref = [], []
                for _ in range(repeats):
                    for i in range(len(c)):
                        t0 = time.process_time()
                        _plain_read(reader, conns, times, i)
                        t1 = time.process_time()
                        br.frame(i)
                        ref.append(t1 - t0)
                        ours.append(time.process_time() - t1)
                ours_ms, ref_ms = np.array(ours) * 1e3, np.array(ref) * 1e3
                out[kind] = {"layout": c.layout.name, "storage": c.storage, "frames": len(c), "color": f"{c.color_camera.width}x{c.color_camera.height}",
                             "depth": f"{c.depth_camera.width}x{c.depth_camera.height}", "ours_ms": float(np.median(ours_ms)),
                             "ours_p90_ms": float(np.percentile(ours_ms, 90)), "ref_ms": float(np.median(ref_ms)),
                             "ratio": float(np.median(ours_ms) / np.median(ref_ms))}  # fmt: skip
    return out


def report(rows: dict[str, dict], loads: tuple[float, float], date: str) -> str:
    lines = [
        f"{SECTION}\n",
        "`bench/bench_bag.py` (`depthruler bench bag --write`): two bags written from one simulated 1280x720 poster frame; "
        "each frame made by `BagReader.frame(i)` (decode, undistort, register, disparity) against the plain rosbags read "
        "of its two messages (index, read, deserialize, pixels as an array) through the same opened reader, interleaved "
        "frame by frame; CPU time of this process, median over the frames and repeats. Targets: registered "
        "<= 1.5x, unregistered Viewer depth <= 5x.\n",
        "| bag | layout | storage | colour / depth | frames | ours CPU median / p90 ms | plain read CPU median ms | ratio | target |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for kind, r in rows.items():
        met = "met" if r["ratio"] <= TARGETS[kind] else "not met"
        lines.append(f"| {kind} | {r['layout']} | {r['storage']} | {r['color']} / {r['depth']} | {r['frames']} | {r['ours_ms']:.2f} / "
                     f"{r['ours_p90_ms']:.2f} | {r['ref_ms']:.2f} | {r['ratio']:.2f}x | <= {TARGETS[kind]}x ({met}) |")  # fmt: skip
    lines.append(f"\nMachine: {machine()}; {date}; 1-minute load average {loads[0]:.2f} before, {loads[1]:.2f} after.\n")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    import os

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=20, help="frames in each bag (default 20)")
    ap.add_argument("--repeats", type=int, default=3, help="passes over the frames (default 3)")
    ap.add_argument("--write", action="store_true", help="record the table in bench/RESULTS.md")
    args = ap.parse_args(argv)
    before = os.getloadavg()[0]
    rows = run(args.frames, args.repeats)
    text = report(rows, (before, os.getloadavg()[0]), time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()))
    print(text)
    if args.write:
        replace_section(SECTION, text)


if __name__ == "__main__":
    main()
