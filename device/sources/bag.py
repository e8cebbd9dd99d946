"""ROS bags as a source: ``bag:PATH[?depth=TOPIC&color=TOPIC&...]`` (read with ``rosbags``, no ROS install).

PATH is a ROS 1 ``.bag`` file, a ROS 2 bag folder (``metadata.yaml`` with MCAP or sqlite3 storage) or a
single ``.mcap`` / ``.db3`` file. Without topic options the layout is recognised:

- ``realsense-viewer``: what the RealSense Viewer and librealsense record, ``/device_0/sensor_N/Depth_0/image/data``
  and ``.../Color_0/image/data``, each with ``.../info/camera_info`` and ``.../tf/G`` (the extrinsics from the
  stream's reference, group G, to that stream: ``p_stream = R p_ref + t``, librealsense's
  ``device::get_extrinsics``), the depth units in ``/device_0/sensor_N/option/Depth Units/value`` and the
  stereo baseline (mm) in ``.../option/Stereo Baseline/value``. Its depth is NOT registered to colour.
- ``realsense-ros``: ``PREFIX/aligned_depth_to_color/image_raw`` (registered) or ``PREFIX/depth/image_rect_raw``
  (not), with ``PREFIX/color/image_raw`` and the ``camera_info`` next to each (PREFIX e.g. ``/camera`` or
  ``/camera/camera``).
- ``depthai-ros``: ``PREFIX/stereo/image_raw`` with ``PREFIX/rgb/image_raw`` (PREFIX e.g. ``/oak``) and their
  ``camera_info``.

``depth=``/``color=`` name the topics of any other bag (``depth_info=``/``color_info=`` their CameraInfo,
else the ``camera_info`` next to the image topic). When nothing matches, :class:`BagLayoutError` lists the
image topics the bag holds.

Registration. Depth whose camera differs from the colour camera (other intrinsics or another optical
frame) is aligned to the colour image as librealsense's ``align`` does: every valid depth pixel's
footprint is back-projected with the depth intrinsics, moved by the depth-to-colour extrinsics, projected
with the colour intrinsics, and where several land on one colour pixel the nearest wins (a z-buffer:
occluded background behind a foreground edge is dropped). Colour pixels no depth pixel reaches stay
invalid. Two differences from librealsense: the aligned value is the depth in the colour camera (``Z``
after the extrinsics), which is what the colour intrinsics need; and a footprint fills the colour pixels
whose centres it holds, where librealsense rounds both corners and covers about one pixel more per axis,
so that neighbours of one surface overlap and the z-buffer keeps the nearer of two noisy samples: on the
simulated frames warped to a camera 5 cm aside and back, that rule measured the poster 14-17 mm off,
this one 0.1-0.8 mm, as replay does (tests/device/test_bag.py). Depth finer than the colour image (several
depth pixels per colour pixel) gives each colour pixel the depth pixel whose footprint holds its centre,
not the nearest of them: warped to half resolution and back, 1.7-7.3 mm instead of 15-17 mm.

The extrinsics come from the Viewer's ``tf`` topics or from ``/tf_static`` (the chain between the two
camera_info ``frame_id``s, as realsense-ros and depthai-ros publish it). Lens distortion in camera_info is ignored (RealSense and OAK depth is rectified).

Depth encodings: ``16UC1``/``mono16`` in depth units (ROS: millimetres; the Viewer: its Depth Units
option) and ``32FC1`` in metres. 0 and NaN are no depth and stay no depth.

Pairing and indexing. A frame is one colour message with the depth message nearest to it in time, if
that is within ``skew_ms`` (default: half the median colour period, between 5 and 50 ms). The times are
the bag's record times from its index, less each topic's recording latency (bag time minus header stamp,
the median over three messages) when both topics' stamps share a clock: registered depth is often
recorded a frame period after its colour. When a frame is read its header stamps are compared and, if
they differ by more than the skew, the neighbour depth with the nearest stamp is used. Opening reads
the bag's index (ROS 1 index records, MCAP message indexes, sqlite3 timestamps), a few small static
messages (camera_info, tf, options) and three messages per image topic; the other images are read and
decoded when their frame is asked for, so a large bag opens in the time its index takes: a 1.04 GB bag
(290 pairs of 1280x720 rgb8 and 848x480 Z16 plus 20 metadata messages each, 6380 messages) opened in
0.11 s (sqlite3), 0.26-0.29 s (MCAP), 0.28-0.36 s (ROS 1) on the shared 2-core dev machine, 2026-12-01;
reading and aligning one of its frames took 0.2-0.3 s.

Disparity. Frames carry disparity (docs/design.md): ``d = fx * B / Z`` with the colour camera's ``fx``
and a baseline ``B``: the recorded stereo baseline when the bag holds it (the Viewer), else the nominal
``DEFAULT_BASELINE_M`` (0.075 m) or ``?baseline=``. Any ``B`` gives back ``Z`` exactly, so lengths do not
depend on it. A depth camera quantizes depth, in steps of its depth unit, not disparity as a stereo
pair at this ``fx`` and ``B`` would: ``meta["depth_unit_m"]`` (None for float depth) carries the step and
``meta["disparity_from_depth"]`` says the disparity is derived, so a reader of the uncertainty knows the
disparity steps are the depth unit's, ``fx * B * unit / Z**2``, not a stereo matcher's.
"""

from __future__ import annotations

import dataclasses
import math
import re
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, MeasureError, PinholeCamera

from device.base import SourceBase, SourceInfo, SourceSpec
from device.sources.depth_folder import DEFAULT_BASELINE_M, depth_to_disparity
from device.errors import RecordingError, SourceError, SourceNotFound
from device.pacing import Pacer
from device.formats.recording import EndOfRecording

BAG_SUFFIXES = (".bag", ".mcap", ".db3")
DEFAULT_ROS_DEPTH_UNIT_M = 0.001  # REP 118: 16UC1 depth is millimetres
MAX_SPLAT_PX = 8  # a depth pixel covers at most this many colour pixels per axis (grazing surfaces)
_VIEWER_DEPTH = re.compile(r"^(/device_\d+/sensor_\d+)/Depth_(\d+)/image/data$")
_VIEWER_COLOR = re.compile(r"^(/device_\d+/sensor_\d+)/Color_(\d+)/image/data$")
_IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")


class BagError(RecordingError):
    """A bag cannot be read as frames; the message names the file or topic and what to do."""


class BagNotFound(BagError, SourceNotFound):
    """The path is not there or is no bag."""


class BagLayoutError(BagError):
    """No known topic layout in the bag (and no topics were named); the message lists the image topics."""


# ---------------------------------------------------------------------------------------------
# geometry


@dataclass(frozen=True)
class Rigid:
    """``p_to = R @ p_from + t`` (metres)."""

    R: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    t: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_arrays(cls, R: np.ndarray, t: np.ndarray) -> Rigid:
        return cls(tuple(tuple(float(v) for v in row) for row in np.asarray(R, float)), tuple(float(v) for v in np.asarray(t, float)))  # type: ignore[arg-type]

    @classmethod
    def from_msg(cls, transform: Any) -> Rigid:
        """From a geometry_msgs/Transform (quaternion x, y, z, w)."""
        q = transform.rotation
        x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
        n = math.sqrt(x * x + y * y + z * z + w * w)
        if not n > 0:
            raise BagError("a recorded transform has a zero quaternion; the extrinsics in the bag are damaged")
        x, y, z, w = x / n, y / n, z / n, w / n
        R = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
        tr = transform.translation
        return cls.from_arrays(R, np.array([tr.x, tr.y, tr.z], float))

    @property
    def rotation(self) -> np.ndarray:
        return np.asarray(self.R, float)

    @property
    def translation(self) -> np.ndarray:
        return np.asarray(self.t, float)

    def then(self, other: Rigid) -> Rigid:
        """Apply ``self`` first, then ``other``."""
        return Rigid.from_arrays(other.rotation @ self.rotation, other.rotation @ self.translation + other.translation)

    def inverse(self) -> Rigid:
        Rt = self.rotation.T
        return Rigid.from_arrays(Rt, -Rt @ self.translation)

    def is_identity(self, tol: float = 1e-9) -> bool:
        return bool(np.allclose(self.rotation, np.eye(3), atol=tol) and np.allclose(self.translation, 0.0, atol=tol))


def align_depth_to_color(depth_m: np.ndarray, depth_cam: PinholeCamera, color_cam: PinholeCamera, depth_to_color: Rigid) -> np.ndarray:
    """Depth (m, depth camera pixels; 0 or NaN = none) -> depth (m) at the colour camera's pixels, NaN = none.

    ``depth_to_color`` maps depth-camera points to colour-camera points (``p_c = R p_d + t``). Each valid
    depth pixel's footprint (its corners at +-0.5 px) is back-projected at its depth, moved to the colour
    camera and projected; it fills the colour pixels whose centres lie inside it (so a lower-resolution
    depth leaves no pinholes), at most ``MAX_SPLAT_PX`` per axis; one holding no centre fills the pixel
    under its centre if no other footprint holds that pixel's centre. Where several fall on one colour
    pixel the nearest wins. The value stored is Z in the colour camera. Pinhole model both sides.
    """
    z_d = np.asarray(depth_m, dtype=np.float64)
    if z_d.shape != (depth_cam.height, depth_cam.width):
        raise BagError(f"depth image is {z_d.shape[1]}x{z_d.shape[0]} but its camera_info says {depth_cam.width}x{depth_cam.height}")
    if depth_cam == color_cam and depth_to_color.is_identity():
        return np.where(np.isfinite(z_d) & (z_d > 0), z_d, np.nan)
    v, u = np.nonzero(np.isfinite(z_d) & (z_d > 0))
    z = z_d[v, u]
    R, t = depth_to_color.rotation, depth_to_color.translation
    u = u.astype(np.float64)
    v = v.astype(np.float64)

    def to_color(du: float, dv: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = (u + du - depth_cam.cx) / depth_cam.fx * z
        y = (v + dv - depth_cam.cy) / depth_cam.fy * z
        X = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
        Y = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
        Z = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return color_cam.fx * X / Z + color_cam.cx, color_cam.fy * Y / Z + color_cam.cy, Z

    xa, ya, _ = to_color(-0.5, -0.5)
    xb, yb, _ = to_color(0.5, 0.5)
    xc, yc, zc = to_color(0.0, 0.0)
    with np.errstate(invalid="ignore"):
        # The colour pixels whose centres lie in the footprint [min, max): neighbouring footprints of one
        # surface tile the image without overlap, so noise is not min-filtered by the z-buffer (librealsense
        # rounds both corners and covers one pixel more per axis, biasing noisy depth towards the camera).
        x0 = np.ceil(np.minimum(xa, xb))
        x1 = np.ceil(np.maximum(xa, xb)) - 1
        y0 = np.ceil(np.minimum(ya, yb))
        y1 = np.ceil(np.maximum(ya, yb)) - 1
        # A footprint smaller than a pixel that holds no centre (depth finer than colour) fills the pixel
        # under its centre, but only where no footprint holding that pixel's centre did: the one that
        # covers the centre is the sample, the others would again be min-filtered.
        primary = (x1 >= x0) & (y1 >= y0)
        x0, x1 = np.where(x1 < x0, np.floor(xc + 0.5), x0), np.where(x1 < x0, np.floor(xc + 0.5), x1)
        y0, y1 = np.where(y1 < y0, np.floor(yc + 0.5), y0), np.where(y1 < y0, np.floor(yc + 0.5), y1)
        keep = (zc > 0) & np.isfinite(x0 + x1 + y0 + y1)
        keep &= (x1 >= 0) & (x0 <= color_cam.width - 1) & (y1 >= 0) & (y0 <= color_cam.height - 1)
    x0, x1, y0, y1, zc, primary = (a[keep] for a in (x0, x1, y0, y1, zc, primary))
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    nx = np.minimum(x1.astype(np.int64) - x0 + 1, MAX_SPLAT_PX)
    ny = np.minimum(y1.astype(np.int64) - y0 + 1, MAX_SPLAT_PX)
    zbuf = np.full(color_cam.width * color_cam.height, np.inf)
    fallback = np.full(color_cam.width * color_cam.height, np.inf)
    # A loop over the footprint's offsets (at most MAX_SPLAT_PX**2, usually 1-4), each vectorised over all pixels.
    for dy in range(int(ny.max(initial=0))):
        for dx in range(int(nx.max(initial=0))):
            xs, ys = x0 + dx, y0 + dy
            m = (dx < nx) & (dy < ny) & (xs >= 0) & (xs < color_cam.width) & (ys >= 0) & (ys < color_cam.height)
            np.minimum.at(zbuf, ys[m & primary] * color_cam.width + xs[m & primary], zc[m & primary])
            np.minimum.at(fallback, ys[m & ~primary] * color_cam.width + xs[m & ~primary], zc[m & ~primary])
    zbuf = np.where(np.isfinite(zbuf), zbuf, fallback)
    zbuf[~np.isfinite(zbuf)] = np.nan
    return zbuf.reshape(color_cam.height, color_cam.width)


def pair_by_time(color_ns: np.ndarray, depth_ns: np.ndarray, max_skew_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (colour, depth) of each colour message and the depth message nearest in time within the skew."""
    c = np.asarray(color_ns, dtype=np.int64)
    d = np.asarray(depth_ns, dtype=np.int64)
    if c.size == 0 or d.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    j = np.clip(np.searchsorted(d, c), 1, d.size - 1) if d.size > 1 else np.zeros(c.size, np.int64)
    if d.size > 1:
        j = np.where(np.abs(d[j - 1] - c) <= np.abs(d[j] - c), j - 1, j)
    ok = np.abs(d[j] - c) <= max_skew_ns
    return np.flatnonzero(ok), j[ok]


# ---------------------------------------------------------------------------------------------
# messages


def _stamp_ns(msg: Any) -> int:
    h = getattr(msg, "header", None)
    if h is None:
        return 0
    return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


def _raw_pixels(msg: Any, topic: str) -> np.ndarray:
    """A sensor_msgs/Image as an H x W (x C) array of its encoding's dtype."""
    enc = str(msg.encoding).lower()
    formats = {"rgb8": (3, "u1"), "bgr8": (3, "u1"), "rgba8": (4, "u1"), "bgra8": (4, "u1"), "mono8": (1, "u1"),
               "8uc1": (1, "u1"), "8uc3": (3, "u1"), "mono16": (1, "u2"), "16uc1": (1, "u2"), "32fc1": (1, "f4"),
               "yuv422": (2, "u1"), "uyvy": (2, "u1"), "yuv422_yuy2": (2, "u1"), "yuyv": (2, "u1")}
    if enc not in formats:
        raise BagError(f"{topic}: image encoding {msg.encoding!r} is not supported; use rgb8/bgr8/mono8/yuv422 for colour, 16UC1 (mm) or 32FC1 (m) for depth")
    ch, kind = formats[enc]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    row = w * ch * dtype.itemsize
    if h < 1 or w < 1 or step < row or data.size < h * step:
        raise BagError(f"{topic}: a {w}x{h} {msg.encoding} image holds {data.size} bytes with step {step}; the message is damaged")
    px = data[: h * step].reshape(h, step)[:, :row].copy().view(dtype).astype(dtype.newbyteorder("="))
    return px.reshape(h, w, ch) if ch > 1 else px.reshape(h, w)


def decode_color(msg: Any, topic: str) -> np.ndarray:
    """A colour Image or CompressedImage message -> H x W x 3 uint8 BGR."""
    import cv2

    if hasattr(msg, "format") and not hasattr(msg, "encoding"):  # sensor_msgs/CompressedImage
        img = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise BagError(f"{topic}: a compressed image ({msg.format}) cannot be decoded")
        return img
    px = _raw_pixels(msg, topic)
    enc = str(msg.encoding).lower()
    conversions = {"rgb8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGBA2BGR, "bgra8": cv2.COLOR_BGRA2BGR,
                   "mono8": cv2.COLOR_GRAY2BGR, "8uc1": cv2.COLOR_GRAY2BGR, "yuv422": cv2.COLOR_YUV2BGR_UYVY,
                   "uyvy": cv2.COLOR_YUV2BGR_UYVY, "yuv422_yuy2": cv2.COLOR_YUV2BGR_YUY2, "yuyv": cv2.COLOR_YUV2BGR_YUY2}
    if enc in conversions:
        return np.ascontiguousarray(cv2.cvtColor(px, conversions[enc]))
    if enc in ("bgr8", "8uc3"):
        return np.ascontiguousarray(px)
    raise BagError(f"{topic}: {msg.encoding} is a depth encoding, not colour; name the colour topic with color=TOPIC")


def decode_depth(msg: Any, topic: str, unit_m: float) -> np.ndarray:
    """A depth Image -> metres (float64), NaN where no depth (0, NaN, negative)."""
    if not hasattr(msg, "encoding"):
        raise BagError(f"{topic}: compressed depth is not supported; record the raw depth topic (16UC1 or 32FC1)")
    enc = str(msg.encoding).lower()
    if enc not in ("16uc1", "mono16", "32fc1"):
        raise BagError(f"{topic}: depth encoding {msg.encoding!r} is not supported; depth must be 16UC1/mono16 (depth units) or 32FC1 (metres)")
    px = _raw_pixels(msg, topic).astype(np.float64)
    z = px if enc == "32fc1" else px * unit_m
    z[~(np.isfinite(z) & (z > 0))] = np.nan
    return z


def camera_from_info(msg: Any, topic: str) -> PinholeCamera:
    """The pinhole camera of a sensor_msgs/CameraInfo (K; ROS 1's ``K`` and ROS 2's ``k`` both read)."""
    k = np.asarray(getattr(msg, "k", getattr(msg, "K", None)), dtype=np.float64).ravel()
    if k.size != 9 or not k[0] > 0 or not k[4] > 0:
        raise BagError(f"{topic}: camera_info has no usable K ({k.tolist()}); the bag's calibration is missing")
    try:
        return PinholeCamera(fx=float(k[0]), fy=float(k[4]), cx=float(k[2]), cy=float(k[5]), width=int(msg.width), height=int(msg.height))
    except MeasureError as exc:
        raise BagError(f"{topic}: camera_info is not a usable camera ({exc})") from exc


# ---------------------------------------------------------------------------------------------
# opening and indexing


def is_bag_path(path: str | Path) -> bool:
    """True when ``path`` looks like a bag: a .bag/.mcap/.db3 file or a ROS 2 bag folder."""
    p = Path(path)
    return (p.is_file() and p.suffix.lower() in BAG_SUFFIXES) or (p.is_dir() and (p / "metadata.yaml").is_file())


def _storage_name(path: Path) -> str:
    if path.suffix.lower() == ".bag":
        return "ROS 1 bag"
    if path.suffix.lower() == ".mcap":
        return "ROS 2 MCAP"
    if path.suffix.lower() == ".db3":
        return "ROS 2 sqlite3"
    text = (path / "metadata.yaml").read_text(errors="replace") if (path / "metadata.yaml").is_file() else ""
    m = re.search(r"storage_identifier:\s*(\S+)", text)
    return f"ROS 2 {m.group(1) if m else 'bag'} folder"


def _open_reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise BagNotFound(f"{path} does not exist; give a ROS 1 .bag, a ROS 2 bag folder or a .mcap/.db3 file")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        found = sorted(p for p in path.iterdir() if p.suffix.lower() in (".mcap", ".db3"))
        if len(found) != 1:
            raise BagNotFound(f"{path} has no metadata.yaml and {len(found)} .mcap/.db3 files; give the bag file itself (bag:{path}/NAME.mcap)")
        path = found[0]
    elif path.is_file() and path.suffix.lower() not in BAG_SUFFIXES:
        raise BagNotFound(f"{path} is not a bag: use a .bag (ROS 1), .mcap or .db3 (ROS 2) file or a ROS 2 bag folder")
    # ROS 1 bags always embed their message definitions; ROS 2 sqlite3 bags before Iron may not.
    store = None if path.suffix.lower() == ".bag" else get_typestore(Stores.ROS2_HUMBLE)
    reader = AnyReader([path], default_typestore=store)
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own ReaderError/AnyReaderError and struct/OS errors on damage
        raise BagError(f"{path} cannot be opened as a bag ({type(exc).__name__}: {exc}); check it is complete (ROS 1: rosbag reindex)") from exc
    return reader


def _mcap_index_times(storage: Any, channel_ids: set[int]) -> list[int] | None:
    """Log times of the channels' messages from an MCAP file's MessageIndex records (no chunk is read);
    None when a chunk has no message index (the writer left them out)."""
    bio = storage.bio
    out: list[int] = []
    if any(not chunk.message_index_offsets for chunk in storage.chunks):
        return None
    for chunk in storage.chunks:
        for cid, offset in chunk.message_index_offsets.items():
            if cid not in channel_ids:
                continue
            bio.seek(offset)
            head = bio.read(9)
            if len(head) != 9 or head[0] != 0x07:
                raise BagError(f"{storage.path}: the MCAP message index at byte {offset} is damaged; re-index the file (mcap recover)")
            (length,) = struct.unpack("<Q", head[1:])
            rec = bio.read(length)
            (nbytes,) = struct.unpack_from("<I", rec, 2)
            pairs = np.frombuffer(rec, dtype="<u8", count=nbytes // 8, offset=6)
            out.extend(int(t) for t in pairs[0::2])
    return out


def topic_times(connections: Sequence[Any]) -> tuple[np.ndarray, bool]:
    """Sorted record times (ns) of all messages of these connections, from the bag's index; and whether
    only the index was read (False: an unindexed MCAP had to be scanned)."""
    from rosbags.rosbag1 import Reader as Reader1
    from rosbags.rosbag2.reader import DirectoryReader
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    times: list[int] = []
    indexed = True
    for conn in connections:
        owner = conn.owner
        if isinstance(owner, Reader1):
            times.extend(e.time for e in owner.indexes[conn.id])
            continue
        storages = owner.storages if isinstance(owner, DirectoryReader) else [owner]
        for st in storages:
            ids = {c.id for c in st.connections if c.topic == conn.topic and c.msgtype == conn.msgtype}
            if not ids:
                continue
            found = None
            if isinstance(st, Sqlite3Reader) and st.dbconn is not None:
                marks = ",".join("?" for _ in ids)
                found = [int(r[0]) for r in st.dbconn.execute(f"SELECT timestamp FROM messages WHERE topic_id IN ({marks})", tuple(ids))]
            elif isinstance(st, McapReader) and st.chunks:
                found = _mcap_index_times(st, ids)
            if found is None:  # an MCAP without message indexes: read it through once
                indexed = False
                found = [ts for _, ts, _ in st.messages([c for c in st.connections if c.id in ids])]
            times.extend(found)
    return np.sort(np.asarray(times, dtype=np.int64)), indexed


@dataclass(frozen=True)
class Layout:
    """Which topics hold the frames, and what is known of them before reading."""

    name: str  # "realsense-viewer" | "realsense-ros" | "depthai-ros" | "topics"
    depth_topic: str
    color_topic: str
    depth_info_topic: str | None
    color_info_topic: str | None
    registered: bool | None = None  # True: the topic is registered depth by name; None: decide from the calibration


def _sibling_info(topic: str, topics: Mapping[str, str]) -> str | None:
    parent = topic.rsplit("/", 1)[0]
    for cand in (parent + "/camera_info", parent + "/info/camera_info", parent.rsplit("/", 1)[0] + "/info/camera_info"):
        if topics.get(cand, "").endswith("CameraInfo"):
            return cand
    return None


def detect_layout(topics: Mapping[str, str], params: Mapping[str, str] | None = None) -> Layout:
    """The layout of a bag from its topics (name -> message type), or the topics named in ``params``."""
    params = params or {}
    images = sorted(t for t, ty in topics.items() if ty in _IMAGE_TYPES)
    if "depth" in params or "color" in params:
        missing = [k for k in ("depth", "color") if k not in params]
        if missing:
            raise BagLayoutError(f"name both topics: bag:PATH?depth=TOPIC&color=TOPIC (missing {missing[0]}=); image topics: {', '.join(images) or 'none'}")
        for key in ("depth", "color"):
            if topics.get(params[key]) not in _IMAGE_TYPES:
                raise BagLayoutError(f"{key}={params[key]} is not an image topic of this bag; image topics: {', '.join(images) or 'none'}")
        d, c = params["depth"], params["color"]
        return Layout("topics", d, c, params.get("depth_info") or _sibling_info(d, topics), params.get("color_info") or _sibling_info(c, topics))
    viewer_d = [m for t in images if (m := _VIEWER_DEPTH.match(t))]
    viewer_c = [m for t in images if (m := _VIEWER_COLOR.match(t))]
    if viewer_d and viewer_c:
        d, c = viewer_d[0].group(0), viewer_c[0].group(0)
        return Layout("realsense-viewer", d, c, _sibling_info(d, topics), _sibling_info(c, topics))
    for t in images:
        for suffix, registered in (("/aligned_depth_to_color/image_raw", True), ("/depth/image_rect_raw", None)):
            prefix = t[: -len(suffix)]
            if t.endswith(suffix) and prefix + "/color/image_raw" in topics:
                c = prefix + "/color/image_raw"
                if registered is None and any(x.endswith("/aligned_depth_to_color/image_raw") for x in images):
                    continue  # prefer the registered topic when both were recorded
                return Layout("realsense-ros", t, c, _sibling_info(t, topics), _sibling_info(c, topics), registered)
    for t in images:
        if t.endswith("/stereo/image_raw") and t[: -len("/stereo/image_raw")] + "/rgb/image_raw" in topics:
            c = t[: -len("/stereo/image_raw")] + "/rgb/image_raw"
            return Layout("depthai-ros", t, c, _sibling_info(t, topics), _sibling_info(c, topics))
    listing = "\n  ".join(f"{t}  [{topics[t]}]" for t in sorted(topics)) or "(none)"
    raise BagLayoutError(
        "no known layout (RealSense Viewer /device_0/sensor_*/Depth_0/image/data, realsense-ros "
        ".../aligned_depth_to_color/image_raw + .../color/image_raw, depthai-ros .../stereo/image_raw + "
        ".../rgb/image_raw) in this bag; name the topics with bag:PATH?depth=TOPIC&color=TOPIC. Its topics:\n  " + listing
    )


@dataclass(frozen=True)
class BagOptions:
    """Spec options: explicit topics, ``baseline`` (m), ``depth_unit`` (m per 16-bit step), ``skew_ms``,
    ``registered`` (treat depth as registered to colour), ``loop``, ``realtime``, ``speed``, ``start``."""

    topics: tuple[tuple[str, str], ...] = ()
    baseline_m: float | None = None
    depth_unit_m: float | None = None
    skew_ms: float | None = None
    registered: bool = False
    loop: bool = False
    realtime: bool = False
    speed: float = 1.0
    start: int = 0

    def __post_init__(self) -> None:
        for name in ("baseline_m", "depth_unit_m", "skew_ms"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise SourceError(f"bag option {name.removesuffix('_m').removesuffix('_ms')}={v} must be a positive number")
        if not (self.speed > 0 and math.isfinite(self.speed)):
            raise SourceError(f"speed={self.speed} must be a positive number (1 = as recorded)")
        if self.start < 0:
            raise SourceError(f"start={self.start} must be a frame index >= 0")


@dataclass(frozen=True)
class BagConfig:
    """A bag source: the bag (ROS 1 .bag, ROS 2 folder or .mcap) and its options."""

    path: Path
    options: BagOptions = BagOptions()


@dataclass(frozen=True)
class BagContents:
    """What a bag holds for depthruler: found at open from the index and the small static messages."""

    path: Path
    storage: str
    layout: Layout
    topics: Mapping[str, str]
    counts: Mapping[str, int]
    color_camera: PinholeCamera
    depth_camera: PinholeCamera
    depth_to_color: Rigid
    extrinsics_from: str  # "registered" | "identity (same frame)" | "viewer tf" | "/tf_static" | "registered=1"
    depth_unit_m: float | None  # None: float depth in metres (32FC1)
    depth_encoding: str
    baseline_m: float
    baseline_from: str
    max_skew_ns: int
    color_ns: np.ndarray = field(repr=False)
    depth_ns: np.ndarray = field(repr=False)
    pairs: tuple[np.ndarray, np.ndarray] = field(repr=False)
    indexed: bool = True
    stamps_comparable: bool = False  # colour and depth header stamps share a clock: they decide the pairs
    latency_ns: tuple[int, int] = (0, 0)  # (colour, depth) bag time minus header stamp, taken off before pairing

    def __len__(self) -> int:
        return int(self.pairs[0].size)

    @property
    def registered(self) -> bool:
        return self.depth_camera == self.color_camera and self.depth_to_color.is_identity()


def _occurrence(times: np.ndarray, i: int) -> int:
    """How many earlier messages of the topic share message ``i``'s time (to pick it among them)."""
    return int(i - np.searchsorted(times, times[i], side="left"))


class BagReader:
    """An opened bag: its contents (index only) and random access to frame ``i``."""

    def __init__(self, config: BagConfig | str | Path, options: BagOptions = BagOptions()) -> None:
        self.config = config if isinstance(config, BagConfig) else BagConfig(Path(config), options)
        self.path = Path(self.config.path)
        self.options = self.config.options
        self._reader = _open_reader(self.path)
        try:
            self.contents = self._index()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        reader, self._reader = getattr(self, "_reader", None), None
        if reader is not None:
            reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- static messages -------------------------------------------------------------------

    def _conns(self, topic: str) -> list[Any]:
        return [c for c in self._reader.connections if c.topic == topic]

    def _first(self, topic: str | None) -> Any | None:
        if not topic:
            return None
        conns = self._conns(topic)
        if not conns:
            return None
        gen = self._reader.messages(connections=conns)
        try:
            for conn, _, raw in gen:
                return self._deserialize(raw, conn, topic)
        finally:
            gen.close()
        return None

    def _deserialize(self, raw: bytes, conn: Any, topic: str) -> Any:
        try:
            return self._reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # rosbags raises KeyError/struct errors/its own on unknown types and damage
            raise BagError(f"{self.path}: a {conn.msgtype} message on {topic} cannot be decoded ({type(exc).__name__}: {exc})") from exc

    def _option(self, sensor_prefix: str, name: str) -> float | None:
        msg = self._first(f"{sensor_prefix}/option/{name}/value")
        return float(f"{float(msg.data):.7g}") if msg is not None else None  # a Float32: 0.0001, not 9.99999975e-05

    def _tf_static(self) -> list[tuple[str, str, Rigid]]:
        edges = []
        for topic in ("/tf_static",):
            for conn in self._conns(topic):
                gen = self._reader.messages(connections=[conn])
                for _, _, raw in gen:
                    for ts in self._deserialize(raw, conn, topic).transforms:
                        edges.append((str(ts.header.frame_id).lstrip("/"), str(ts.child_frame_id).lstrip("/"), Rigid.from_msg(ts.transform)))
        return edges

    def _chain(self, src: str, dst: str) -> Rigid | None:
        """``p_dst = T p_src`` from /tf_static (each edge: ``p_parent = T p_child``), or None without a path."""
        edges = self._tf_static()
        graph: dict[str, list[tuple[str, Rigid]]] = {}
        for parent, child, T in edges:
            graph.setdefault(child, []).append((parent, T))  # child -> parent
            graph.setdefault(parent, []).append((child, T.inverse()))
        seen = {src: Rigid()}
        todo = [src]
        while todo:
            node = todo.pop(0)
            for nxt, T in graph.get(node, []):
                if nxt not in seen:
                    seen[nxt] = seen[node].then(T)
                    todo.append(nxt)
        return seen.get(dst)

    # -- index ---------------------------------------------------------------------------------

    def _index(self) -> BagContents:
        reader, opts = self._reader, self.options
        topics = {c.topic: c.msgtype for c in reader.connections}
        layout = detect_layout(topics, dict(opts.topics))
        color_info = self._first(layout.color_info_topic)
        if color_info is None:
            raise BagError(
                f"{self.path}: no camera_info for the colour topic {layout.color_topic} "
                f"({layout.color_info_topic or 'none found next to it'}); name it with color_info=TOPIC"
            )
        color_cam = camera_from_info(color_info, layout.color_info_topic or "")
        depth_info = self._first(layout.depth_info_topic)
        if depth_info is not None:
            depth_cam = camera_from_info(depth_info, layout.depth_info_topic or "")
        elif layout.registered or opts.registered:
            depth_cam = color_cam
        else:
            raise BagError(f"{self.path}: no camera_info for the depth topic {layout.depth_topic}; name it with depth_info=TOPIC, "
                           "or add registered=1 if the depth is registered to the colour image")
        T, how = self._extrinsics(layout, depth_info, color_info, depth_cam, color_cam)
        unit, encoding, baseline, baseline_from = self._units(layout)
        color_ns, idx_c = topic_times(self._conns(layout.color_topic))
        depth_ns, idx_d = topic_times(self._conns(layout.depth_topic))
        lat_c, lat_d = self._latency(layout.color_topic, color_ns), self._latency(layout.depth_topic, depth_ns)
        # Stamps on one clock (within a second of each other): pair on bag time minus each topic's latency, so
        # registered depth published a frame period after its colour still pairs with it.
        stamps = lat_c is not None and lat_d is not None and abs(lat_c - lat_d) < 1_000_000_000
        lat_c, lat_d = (lat_c, lat_d) if stamps else (0, 0)
        if opts.skew_ms is not None:
            skew = int(opts.skew_ms * 1e6)
        elif color_ns.size > 1:
            skew = int(np.clip(0.5 * np.median(np.diff(color_ns)), 5e6, 50e6))
        else:
            skew = int(50e6)
        return BagContents(
            path=self.path,
            storage=_storage_name(self.path),
            layout=layout,
            topics=topics,
            counts={c.topic: int(c.msgcount) for c in reader.connections},
            color_camera=color_cam,
            depth_camera=depth_cam,
            depth_to_color=T,
            extrinsics_from=how,
            depth_unit_m=unit,
            depth_encoding=encoding,
            baseline_m=baseline,
            baseline_from=baseline_from,
            max_skew_ns=skew,
            color_ns=color_ns,
            depth_ns=depth_ns,
            pairs=pair_by_time(color_ns - lat_c, depth_ns - lat_d, skew),
            indexed=idx_c and idx_d,
            stamps_comparable=stamps,
            latency_ns=(int(lat_c), int(lat_d)),
        )

    def _extrinsics(self, layout: Layout, depth_info: Any, color_info: Any, depth_cam: PinholeCamera, color_cam: PinholeCamera) -> tuple[Rigid, str]:
        if self.options.registered:
            return Rigid(), "registered=1"
        if layout.registered:
            return Rigid(), "registered topic"
        if layout.name == "realsense-viewer":
            T = self._viewer_tf(layout)
            if T is not None:
                return T, "viewer tf"
        fd = str(getattr(getattr(depth_info, "header", None), "frame_id", "") or "").lstrip("/")
        fc = str(getattr(getattr(color_info, "header", None), "frame_id", "") or "").lstrip("/")
        if fd and fd == fc:
            return Rigid(), "same frame_id"
        if fd and fc:
            T = self._chain(fd, fc)
            if T is not None:
                return T, "/tf_static"
        if not fd and not fc and depth_cam == color_cam:
            return Rigid(), "same camera_info"
        raise BagError(
            f"{self.path}: depth ({layout.depth_topic}, frame {fd or '?'}) is not registered to colour ({layout.color_topic}, "
            f"frame {fc or '?'}) and the bag holds no transform between them (no Viewer tf topics, no /tf_static path); "
            "record /tf_static, use the registered depth topic, or add registered=1 if it is registered"
        )

    def _viewer_tf(self, layout: Layout) -> Rigid | None:
        """Depth-to-colour extrinsics from the Viewer's ``STREAM/tf/G`` topics (``p_stream = T p_ref``)."""
        def tf_of(image_topic: str) -> dict[str, Rigid]:
            stream = image_topic.removesuffix("/image/data")
            out = {}
            for t in self._reader.topics:
                if t.startswith(stream + "/tf/"):
                    msg = self._first(t)
                    if msg is not None:
                        out[t.rsplit("/", 1)[1]] = Rigid.from_msg(msg)
            return out

        d, c = tf_of(layout.depth_topic), tf_of(layout.color_topic)
        for group in sorted(set(d) & set(c)):
            return d[group].inverse().then(c[group])
        if c and not d:  # the depth stream is the reference
            return next(iter(c.values()))
        return None

    def _latency(self, topic: str, times: np.ndarray) -> int | None:
        """Median of bag time minus header stamp over three messages (first, middle, last), or None
        without stamps: a topic's recording latency, from a fixed number of reads whatever the bag's size."""
        lags = []
        for i in sorted({0, times.size // 2, times.size - 1}):
            if 0 <= i < times.size:
                msg, t = self._message(topic, times, i)
                if _stamp_ns(msg):
                    lags.append(t - _stamp_ns(msg))
        return int(np.median(lags)) if lags else None

    def _units(self, layout: Layout) -> tuple[float | None, str, float, str]:
        sensor = layout.depth_topic.split("/Depth_")[0] if layout.name == "realsense-viewer" else ""
        unit = self.options.depth_unit_m
        recorded_unit = self._option(sensor, "Depth Units") if sensor else None
        if unit is None:
            unit = recorded_unit if recorded_unit and recorded_unit > 0 else DEFAULT_ROS_DEPTH_UNIT_M
        baseline_from = "nominal DEFAULT_BASELINE_M"
        baseline = DEFAULT_BASELINE_M
        stereo_mm = self._option(sensor, "Stereo Baseline") if sensor else None
        if self.options.baseline_m is not None:
            baseline, baseline_from = self.options.baseline_m, "baseline= option"
        elif stereo_mm and stereo_mm > 0:
            baseline, baseline_from = stereo_mm / 1000.0, "recorded Stereo Baseline option"
        first = self._first(layout.depth_topic)  # one image: its encoding says whether depth is in units or metres
        encoding = str(getattr(first, "encoding", "compressed"))
        return (None if encoding.lower() == "32fc1" else unit), encoding, baseline, baseline_from

    # -- frames --------------------------------------------------------------------------------

    def _message(self, topic: str, times: np.ndarray, i: int) -> tuple[Any, int]:
        t = int(times[i])
        k = _occurrence(times, i)
        gen = self._reader.messages(connections=self._conns(topic), start=t, stop=t + 1)
        try:
            for j, (conn, ts, raw) in enumerate(gen):
                if j == k:
                    return self._deserialize(raw, conn, topic), ts
        finally:
            gen.close()
        raise BagError(f"{self.path}: message {i} of {topic} (time {t} ns) listed in the index is missing; the bag is damaged")

    def frame(self, i: int) -> Frame:
        """Frame ``i`` (0-based among the colour/depth pairs): colour, registered disparity and meta."""
        if self._reader is None:
            raise SourceError("the bag is closed")
        c = self.contents
        n = len(c)
        if not 0 <= i < n:
            raise IndexError(f"frame {i} is out of range: {self.path} has {n} colour/depth pairs")
        ci, di = int(c.pairs[0][i]), int(c.pairs[1][i])
        color_msg, color_t = self._message(c.layout.color_topic, c.color_ns, ci)
        depth_msg, depth_t = self._message(c.layout.depth_topic, c.depth_ns, di)
        sc, sd = _stamp_ns(color_msg), _stamp_ns(depth_msg)
        if c.stamps_comparable and abs(sd - sc) > c.max_skew_ns:
            # Bag times pair the wrong neighbour when one topic is delayed more than the skew; stamps decide.
            for dj in (di - 1, di + 1, di - 2, di + 2):
                if 0 <= dj < c.depth_ns.size:
                    msg, t = self._message(c.layout.depth_topic, c.depth_ns, dj)
                    if abs(_stamp_ns(msg) - sc) < abs(sd - sc):
                        depth_msg, depth_t, sd, di = msg, t, _stamp_ns(msg), dj
        image = decode_color(color_msg, c.layout.color_topic)
        cam = c.color_camera
        if image.shape[:2] != (cam.height, cam.width):
            cam = cam.scaled(image.shape[1], image.shape[0])
        depth = decode_depth(depth_msg, c.layout.depth_topic, c.depth_unit_m or DEFAULT_ROS_DEPTH_UNIT_M)
        dcam = c.depth_camera
        if depth.shape != (dcam.height, dcam.width):
            dcam = dcam.scaled(depth.shape[1], depth.shape[0])
        z = align_depth_to_color(depth, dcam, cam, c.depth_to_color)
        skew = (sd - sc) / 1e9 if c.stamps_comparable else (depth_t - color_t) / 1e9
        meta = {
            "source": "bag",
            "bag": str(self.path),
            "layout": c.layout.name,
            "frame_index": i,
            "color_topic": c.layout.color_topic,
            "depth_topic": c.layout.depth_topic,
            "color_message": ci,
            "depth_message": di,
            "skew_s": skew,
            "registered_in_bag": c.registered,
            "extrinsics": c.extrinsics_from,
            "depth_unit_m": None if str(depth_msg.encoding).lower() == "32fc1" else c.depth_unit_m,
            "depth_encoding": str(depth_msg.encoding),
            "disparity_from_depth": True,
            "baseline": c.baseline_from,
        }
        return Frame(
            image=image,
            disparity=depth_to_disparity(z, cam.fx, c.baseline_m),
            camera=cam,
            baseline_m=c.baseline_m,
            timestamp=(sc or color_t) / 1e9,  # the colour's stamp (device clock) where it has one
            meta=meta,
        )


def summarize_bag(path: str | Path, options: BagOptions = BagOptions()) -> dict[str, Any]:
    """What `depthruler replay BAG` prints: storage, layout, topics, pairs, calibration (index only)."""
    with BagReader(path, options) as br:
        c = br.contents
        cn = c.color_ns
        dur = float(cn[-1] - cn[0]) / 1e9 if cn.size > 1 else 0.0
        lat_c, lat_d = c.latency_ns
        skews = ((c.depth_ns[c.pairs[1]] - lat_d) - (c.color_ns[c.pairs[0]] - lat_c)) / 1e9
        size = sum(p.stat().st_size for p in ([c.path] if c.path.is_file() else c.path.rglob("*")) if p.is_file())
        return {
            "path": str(c.path),
            "storage": c.storage,
            "layout": c.layout.name,
            "color_topic": c.layout.color_topic,
            "depth_topic": c.layout.depth_topic,
            "color_messages": int(c.color_ns.size),
            "depth_messages": int(c.depth_ns.size),
            "frames": len(c),
            "max_skew_ms": c.max_skew_ns / 1e6,
            "latency_ms": {"color": lat_c / 1e6, "depth": lat_d / 1e6} if c.stamps_comparable else None,
            "skew_ms": {"median": float(np.median(np.abs(skews)) * 1e3), "max": float(np.abs(skews).max() * 1e3)} if skews.size else None,
            "duration_s": dur,
            "fps": (cn.size - 1) / dur if dur > 0 else None,
            "color_camera": dataclasses.asdict(c.color_camera),
            "depth_camera": dataclasses.asdict(c.depth_camera),
            "registered": c.registered,
            "extrinsics": c.extrinsics_from,
            "depth_to_color": {"R": [list(r) for r in c.depth_to_color.R], "t": list(c.depth_to_color.t)},
            "depth_encoding": c.depth_encoding,
            "depth_unit_m": c.depth_unit_m,
            "baseline_m": c.baseline_m,
            "baseline": c.baseline_from,
            "indexed": c.indexed,
            "size_bytes": size,
            "topics": {t: {"type": ty, "messages": c.counts.get(t, 0)} for t, ty in sorted(c.topics.items())},
        }


# ---------------------------------------------------------------------------------------------
# the source


class BagSource(SourceBase):
    """The colour/depth pairs of a bag as frames, in order; random access with ``frame(i)`` and ``seek(i)``."""

    def __init__(self, config: BagConfig | str | Path, options: BagOptions = BagOptions()) -> None:
        self.config = config if isinstance(config, BagConfig) else BagConfig(Path(config), options)
        self.path = Path(self.config.path)
        self.options = self.config.options
        self.info = SourceInfo(kind="bag", name=self.path.name)
        self.bag: BagReader | None = None
        self._pos = 0
        self._pacer = Pacer()

    def open(self) -> None:
        bag = BagReader(self.path, self.options)
        c = bag.contents
        if len(c) == 0:
            bag.close()
            raise BagError(
                f"{self.path}: no colour message of {c.layout.color_topic} ({c.color_ns.size}) has a depth message of "
                f"{c.layout.depth_topic} ({c.depth_ns.size}) within {c.max_skew_ns / 1e6:.1f} ms; allow more with skew_ms=N"
            )
        if self.options.start >= len(c):
            bag.close()
            raise SourceError(f"start={self.options.start} is past the end: {self.path} has {len(c)} frames")
        t = c.color_ns[c.pairs[0]]
        offsets = (t - t[0]) / 1e9
        self._pacer = Pacer(offsets, self.options.speed)
        fps = (len(t) - 1) / offsets[-1] if len(t) > 1 and offsets[-1] > 0 else 0.0
        self.bag, self._pos = bag, self.options.start
        self.info = SourceInfo(
            kind="bag",
            name=self.path.name,
            width=c.color_camera.width,
            height=c.color_camera.height,
            fps=fps,
            extra={"path": str(self.path), "frames": len(c), "layout": c.layout.name, "storage": c.storage,
                   "baseline_m": c.baseline_m, "depth_unit_m": c.depth_unit_m},
        )
        super().open()

    def __len__(self) -> int:
        return len(self.bag.contents) if self.bag is not None else 0

    def frame(self, i: int) -> Frame:
        if self.bag is None or not self.is_open:
            raise SourceError("the bag source is not open; call open() or use it in a with block")
        return self.bag.frame(i)

    def seek(self, i: int) -> None:
        """Make frame ``i`` the next one ``read`` returns."""
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} is out of range: {self.path} has {len(self)} frames")
        self._pos = i
        self._pacer.restart()

    def read(self, timeout_s: float = 1.0) -> Frame:
        if self.bag is None or not self.is_open:
            raise SourceError("the bag source is not open; call open() or use it in a with block")
        n = len(self)
        if self._pos >= n:
            if not self.options.loop:
                raise EndOfRecording(f"the bag {self.path} reached its end after {n} frames; use bag:PATH?loop=1 to repeat it")
            self._pos = 0
            self._pacer.restart()
        i = self._pos
        if self.options.realtime:
            self._pacer.wait_for(i, timeout_s, "the bag")
        self._pos += 1
        return self.bag.frame(i)

    def close(self) -> None:
        if self.bag is not None:
            self.bag.close()
        self.bag = None
        super().close()


_PARAMS = ("depth", "color", "depth_info", "color_info", "baseline", "depth_unit", "skew_ms", "registered", "loop", "realtime", "speed", "start")


def options_from_spec(spec: SourceSpec) -> BagOptions:
    spec.check_keys(_PARAMS)

    try:
        start = int(spec.params.get("start", "0"))
    except ValueError:
        raise SourceError(f"bag option start={spec.params['start']!r} must be a frame index") from None
    speed = spec.number("speed")
    return BagOptions(
        topics=tuple((k, spec.params[k]) for k in ("depth", "color", "depth_info", "color_info") if spec.params.get(k)),
        baseline_m=spec.number("baseline"),
        depth_unit_m=spec.number("depth_unit"),
        skew_ms=spec.number("skew_ms"),
        registered=spec.flag("registered", False),
        loop=spec.flag("loop", False),
        realtime=spec.flag("realtime", False),
        speed=1.0 if speed is None else speed,  # not `or 1.0`: speed=0 is refused, not played at 1
        start=start,
    )


def config_from_spec(spec: SourceSpec) -> BagConfig:
    """BagConfig from ``bag:PATH?depth=TOPIC&color=TOPIC&baseline=0.05&depth_unit=0.001&skew_ms=20&loop=1``."""
    if not spec.target:
        raise BagNotFound("bag needs a path: bag:path/to/file.bag, bag:path/to/ros2_bag_folder or bag:path/to/file.mcap")
    return BagConfig(Path(spec.target), options_from_spec(spec))


__all__ = [
    "BagConfig",
    "BagContents",
    "BagError",
    "BagLayoutError",
    "BagNotFound",
    "BagOptions",
    "BagReader",
    "BagSource",
    "Layout",
    "Rigid",
    "align_depth_to_color",
    "camera_from_info",
    "decode_color",
    "decode_depth",
    "config_from_spec",
    "detect_layout",
    "is_bag_path",
    "pair_by_time",
    "summarize_bag",
    "topic_times",
]
