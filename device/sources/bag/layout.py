"""Which topics of a bag hold depth, colour and their camera_info: the RealSense Viewer, realsense-ros and
depthai-ros layouts recognised by topic name, or the topics a spec names."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from device.sources.bag.errors import BagLayoutError

_VIEWER_DEPTH = re.compile(r"^(/device_\d+/sensor_\d+)/Depth_(\d+)/image/data$")
_VIEWER_COLOR = re.compile(r"^(/device_\d+/sensor_\d+)/Color_(\d+)/image/data$")
_IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")


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
