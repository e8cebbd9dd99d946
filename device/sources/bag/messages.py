"""ROS message decoding: Image / CompressedImage to BGR colour or depth in metres, CameraInfo to a camera.

Depth encodings: ``16UC1``/``mono16`` in depth units (ROS: millimetres, REP 118) and ``32FC1`` in metres;
0, NaN and negatives are no depth. Colour: rgb8/bgr8/rgba8/bgra8/mono8/yuv422 or a compressed image.
Lens distortion in camera_info is read and undone by ``undistort``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from measure import MeasureError, PinholeCamera

from device.sources.bag.errors import BagError

DEFAULT_ROS_DEPTH_UNIT_M = 0.001  # REP 118: 16UC1 depth is millimetres


def _stamp_ns(msg: Any) -> int:
    h = getattr(msg, "header", None)
    if h is None:
        return 0
    return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


def _raw_pixels(msg: Any, topic: str, *, copy: bool = True) -> np.ndarray:
    """A sensor_msgs/Image as an H x W (x C) array of its encoding's dtype: a copy, or with ``copy=False``
    a read-only view of the message's bytes where their byte order is native."""
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
    px = data[: h * step].reshape(h, step)[:, :row]
    px = (np.array(px) if copy else px).view(dtype)  # the message's bytes are read-only
    if not dtype.isnative:
        px = px.byteswap().view(dtype.newbyteorder("="))
    return px.reshape(h, w, ch) if ch > 1 else px.reshape(h, w)


def decode_color(msg: Any, topic: str) -> np.ndarray:
    """A colour Image or CompressedImage message -> H x W x 3 uint8 BGR."""
    import cv2

    if hasattr(msg, "format") and not hasattr(msg, "encoding"):  # sensor_msgs/CompressedImage
        img = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise BagError(f"{topic}: a compressed image ({msg.format}) cannot be decoded")
        return img
    enc = str(msg.encoding).lower()
    conversions = {"rgb8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGBA2BGR, "bgra8": cv2.COLOR_BGRA2BGR,
                   "mono8": cv2.COLOR_GRAY2BGR, "8uc1": cv2.COLOR_GRAY2BGR, "yuv422": cv2.COLOR_YUV2BGR_UYVY,
                   "uyvy": cv2.COLOR_YUV2BGR_UYVY, "yuv422_yuy2": cv2.COLOR_YUV2BGR_YUY2, "yuyv": cv2.COLOR_YUV2BGR_YUY2}
    px = _raw_pixels(msg, topic, copy=enc not in conversions)  # a conversion makes the one copy
    if enc in conversions:
        try:
            return np.ascontiguousarray(cv2.cvtColor(px, conversions[enc]))
        except cv2.error as exc:  # e.g. a yuv422 image of odd width
            raise BagError(f"{topic}: a {msg.width}x{msg.height} {msg.encoding} image cannot be converted to colour ({exc.err})") from exc
    if enc in ("bgr8", "8uc3"):
        return np.ascontiguousarray(px)
    raise BagError(f"{topic}: {msg.encoding} is a depth encoding, not colour; name the colour topic with color=TOPIC")


def depth_pixels(msg: Any, topic: str) -> np.ndarray:
    """A depth Image's pixels as they are, read-only: uint16 depth units (``16UC1``/``mono16``) or float32
    metres (``32FC1``); 0, NaN and negatives are no depth."""
    if not hasattr(msg, "encoding"):
        raise BagError(f"{topic}: compressed depth is not supported; record the raw depth topic (16UC1 or 32FC1)")
    enc = str(msg.encoding).lower()
    if enc not in ("16uc1", "mono16", "32fc1"):
        raise BagError(f"{topic}: depth encoding {msg.encoding!r} is not supported; depth must be 16UC1/mono16 (depth units) or 32FC1 (metres)")
    return _raw_pixels(msg, topic, copy=False)


def decode_depth(msg: Any, topic: str, unit_m: float) -> np.ndarray:
    """A depth Image -> metres (float32), NaN where no depth (0, NaN, negative)."""
    return pixels_to_metres(depth_pixels(msg, topic), unit_m)


def pixels_to_metres(px: np.ndarray, unit_m: float) -> np.ndarray:
    """:func:`depth_pixels` -> metres (float32), NaN where no depth: in place, ``(z * q) / q`` with
    ``q = (px > 0)`` as 1 or 0 is ``z`` exactly where ``q`` is 1 and ``0 / 0`` (NaN) where it is 0, in
    whole-array passes (a masked assignment over scattered holes runs several times slower)."""
    z = px.astype(np.float32)
    if px.dtype != np.float32:
        z *= np.float32(unit_m)
    q = (px > 0).view(np.uint8)  # NaN compares false
    with np.errstate(invalid="ignore", divide="ignore"):
        np.multiply(z, q, out=z)
        return np.divide(z, q, out=z)


def pixels_to_disparity(px: np.ndarray, unit_m: float, fx: float, baseline_m: float) -> np.ndarray:
    """:func:`depth_pixels` -> disparity ``d = fx * B / Z`` (float32 px), NaN where no depth: one
    compiled pass, the float32 division ``k / depth`` with ``k = fx * B / unit``."""
    from device.sources.bag.kernels import disparity_from_pixels  # numba compiles on first use: `import device` stays fast

    k = fx * baseline_m / (1.0 if px.dtype == np.float32 else unit_m)
    return disparity_from_pixels(np.ascontiguousarray(px, dtype=px.dtype.newbyteorder("=")), k)


def camera_from_info(msg: Any, topic: str) -> PinholeCamera:
    """The pinhole camera of a sensor_msgs/CameraInfo (K; ROS 1's ``K`` and ROS 2's ``k`` both read)."""
    k = np.asarray(getattr(msg, "k", getattr(msg, "K", None)), dtype=np.float64).ravel()
    if k.size != 9 or not k[0] > 0 or not k[4] > 0:
        raise BagError(f"{topic}: camera_info has no usable K ({k.tolist()}); the bag's calibration is missing")
    try:
        return PinholeCamera(fx=float(k[0]), fy=float(k[4]), cx=float(k[2]), cy=float(k[5]), width=int(msg.width), height=int(msg.height))
    except MeasureError as exc:
        raise BagError(f"{topic}: camera_info is not a usable camera ({exc})") from exc
