"""An opened bag: its contents from the index and a few static messages, and random access to frame ``i``.

Steps at open: detect the layout, read the camera_info of both topics, the depth-to-colour extrinsics (the
Viewer's ``tf`` topics or the ``/tf_static`` chain between the two ``frame_id``s), depth units and
baseline and the lens distortion of both cameras, then each image topic's times from the index and its recording latency (bag time minus header
stamp, median of three messages) and pair colour with the nearest depth within ``skew_ms`` (default half
the median colour period, 5-50 ms). A frame reads and decodes its two messages only when asked for,
re-pairs by header stamp when they differ by more than the skew, resamples a distorted colour image and
its depth onto pinhole images of their K (``undistort``), registers depth to colour and returns
disparity ``d = fx * B / Z`` (m, px). Why and how fast: docs/decisions/bag-source.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, MeasureError, PinholeCamera

from device.errors import SourceError
from device.sources.bag.config import BagConfig, BagOptions
from device.sources.bag.errors import BagError
from device.sources.bag.geometry import Rigid, align_depth_to_color, pair_by_time
from device.sources.bag.layout import Layout, detect_layout
from device.sources.bag.messages import (DEFAULT_ROS_DEPTH_UNIT_M, _stamp_ns, camera_from_info, decode_color, depth_pixels,
                                         pixels_to_disparity, pixels_to_metres)
from device.sources.bag.storage import _open_reader, _storage_name, topic_times
from device.sources.bag.undistort import Distortion, distortion_from_info, remap, undistort_maps
from device.sources.depth_folder import DEFAULT_BASELINE_M


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
    color_distortion: Distortion = Distortion()  # the colour camera_info's; frames are undistorted by it
    depth_distortion: Distortion = Distortion()  # the depth camera_info's (the colour's when depth has none)

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
        self._undistort: dict[tuple[PinholeCamera, Distortion], tuple[np.ndarray, np.ndarray] | None] = {}
        self._topic_conns: dict[str, list[Any]] = {}
        self._reader = _open_reader(self.path)
        try:
            self.contents = self._index()
            self._identity = self.contents.depth_to_color.is_identity()
            self._registered = self.contents.registered
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
        if topic not in self._topic_conns:
            self._topic_conns[topic] = [c for c in self._reader.connections if c.topic == topic]
        return self._topic_conns[topic]

    def _first(self, topic: str | None, *, damaged_ok: bool = False) -> Any | None:
        """The first message of ``topic`` (None without one); ``damaged_ok``: the first that decodes, None if
        none does (an image topic whose frames are damaged still opens; its frames are skipped when read)."""
        if not topic:
            return None
        conns = self._conns(topic)
        if not conns:
            return None
        gen = self._reader.messages(connections=conns)
        try:
            for conn, _, raw in gen:
                try:
                    return self._deserialize(raw, conn, topic)
                except BagError:
                    if not damaged_ok:
                        raise
        except BagError:
            raise
        except Exception as exc:  # rosbags' readers raise their own, struct, zstd/lz4 and OS errors on a damaged chunk
            if not damaged_ok:
                raise BagError(f"{self.path}: the messages of {topic} cannot be read ({type(exc).__name__}: {exc}); "
                               "the bag is damaged") from exc
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
        color_dist = distortion_from_info(color_info, layout.color_info_topic or "")
        depth_info = self._first(layout.depth_info_topic)
        if depth_info is not None:
            depth_cam = camera_from_info(depth_info, layout.depth_info_topic or "")
            depth_dist = distortion_from_info(depth_info, layout.depth_info_topic or "")
        elif layout.registered or opts.registered:
            depth_cam, depth_dist = color_cam, color_dist
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
            color_distortion=color_dist,
            depth_distortion=depth_dist,
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
                try:
                    msg, t = self._message(topic, times, i)
                except BagError:
                    continue  # a damaged message gives no sample; its frame is skipped when read
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
        # One image: its encoding says whether depth is in units or metres.
        first = self._first(layout.depth_topic, damaged_ok=True)
        encoding = "unreadable" if first is None else str(getattr(first, "encoding", "compressed"))
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
        except BagError:
            raise
        except Exception as exc:  # rosbags' readers raise their own, struct, zstd/lz4 and OS errors on a damaged chunk
            raise BagError(f"{self.path}: message {i} of {topic} (time {t} ns) cannot be read ({type(exc).__name__}: {exc}); "
                           "the bag is damaged there") from exc
        finally:
            gen.close()
        raise BagError(f"{self.path}: message {i} of {topic} (time {t} ns) listed in the index is missing; the bag is damaged")

    def _maps(self, cam: PinholeCamera, dist: Distortion) -> tuple[np.ndarray, np.ndarray] | None:
        """Undistortion maps of a camera, computed once per (camera, distortion)."""
        key = (cam, dist)
        if key not in self._undistort:
            self._undistort[key] = undistort_maps(cam, dist)
        return self._undistort[key]

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
                    try:
                        msg, t = self._message(c.layout.depth_topic, c.depth_ns, dj)
                    except BagError:
                        continue  # a damaged neighbour is no candidate; the frame keeps the depth it has
                    if abs(_stamp_ns(msg) - sc) < abs(sd - sc):
                        depth_msg, depth_t, sd, di = msg, t, _stamp_ns(msg), dj
        image = decode_color(color_msg, c.layout.color_topic)
        depth = depth_pixels(depth_msg, c.layout.depth_topic)  # depth units or metres, as recorded
        unit = c.depth_unit_m or DEFAULT_ROS_DEPTH_UNIT_M
        cam, dcam = c.color_camera, c.depth_camera
        try:
            if image.shape[:2] != (cam.height, cam.width):
                cam = cam.scaled(image.shape[1], image.shape[0])
            if depth.shape != (dcam.height, dcam.width):
                dcam = dcam.scaled(depth.shape[1], depth.shape[0])
        except MeasureError as exc:
            raise BagError(f"{self.path}: frame {i}'s images ({image.shape[1]}x{image.shape[0]} colour, {depth.shape[1]}x"
                           f"{depth.shape[0]} depth) do not fit their camera_info ({exc}); the messages are damaged") from exc
        # Distorted images onto the pinhole images of their K: colour and its registered depth by the same
        # map, so they stay registered; clicked pixels then back-project with K alone.
        image = remap(image, self._maps(cam, c.color_distortion), nearest=False)
        depth_maps = self._maps(dcam, c.depth_distortion)
        if depth_maps is None and dcam == cam and self._identity:
            disparity = pixels_to_disparity(depth, unit, cam.fx, c.baseline_m)  # registered: one pass from the pixels
        else:
            if depth_maps is not None:  # resampled in metres
                depth = remap(pixels_to_metres(depth, unit), depth_maps, nearest=True)
            units = unit if depth.dtype == np.uint16 else 0.0  # 16-bit units go to the registration as they are
            disparity = align_depth_to_color(depth, dcam, cam, c.depth_to_color, disparity_k=cam.fx * c.baseline_m, depth_unit_m=units)
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
            "registered_in_bag": self._registered,
            "extrinsics": c.extrinsics_from,
            "depth_unit_m": None if str(depth_msg.encoding).lower() == "32fc1" else c.depth_unit_m,
            "depth_encoding": str(depth_msg.encoding),
            "disparity_from_depth": True,
            "baseline": c.baseline_from,
            "color_distortion": "none" if c.color_distortion.is_none else c.color_distortion.model,
            "undistorted": not (c.color_distortion.is_none and c.depth_distortion.is_none),
        }
        return Frame(
            image=image,
            disparity=disparity,
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
            "color_distortion": dataclasses.asdict(c.color_distortion),
            "depth_distortion": dataclasses.asdict(c.depth_distortion),
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
