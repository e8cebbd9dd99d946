"""DepthAI messages to frames: depth (uint16 mm) to disparity (px) at the output camera's focal length,
the v3 confidence map to [0, 1], and a queue read with DepthAI's failures as typed errors."""

from __future__ import annotations

from datetime import timedelta

import cv2
import depthai as dai
import numpy as np

from measure import Frame, PinholeCamera

from device.errors import CalibrationError, SourceDisconnected, SourceError, SourceTimeout

# How far (relative) a depth frame's aspect ratio may be from the image's before it is refused: a
# rounding of odd sizes (e.g. 1280x720 -> 639x360), not a different field of view.
ASPECT_TOLERANCE = 0.01


class DepthNotRegistered(CalibrationError):
    """A depth (or confidence) frame does not cover the image it should be registered to."""


def check_registered(what: str, shape: tuple[int, ...], width: int, height: int) -> None:
    """Raise :class:`DepthNotRegistered` unless a ``shape`` (rows, cols) frame has the image's aspect
    ratio, so that resizing it to ``width`` x ``height`` pixels maps the same field of view."""
    h_d, w_d = int(shape[0]), int(shape[1])
    if h_d <= 0 or w_d <= 0 or abs(w_d * height - width * h_d) > ASPECT_TOLERANCE * width * h_d:
        raise DepthNotRegistered(
            f"the OAK's {what} is {w_d}x{h_d} but the image is {width}x{height} (aspect {w_d / max(h_d, 1):.3f} "
            f"against {width / height:.3f}): the {what} is not registered to the image and cannot be resized onto it. "
            "Use align=color (depth aligned on the device to the colour camera), or align=left (the rectified "
            f"left image at mono_size), or set size= to the aspect of mono_size (e.g. size={round(height * w_d / h_d)}x{height})"
        )

def depth_to_disparity(depth_mm: np.ndarray, fx: float, baseline_m: float) -> np.ndarray:
    """Disparity (float32 pixels, NaN invalid) at focal length ``fx`` (pixels) from depth in mm.

    ``d = fx * B / Z`` (docs/design.md, doffs = 0) with B in metres and Z = depth_mm / 1000;
    depth 0 is DepthAI's "no data".
    """
    z = np.asarray(depth_mm)
    if z.ndim != 2:
        raise SourceError(f"depth must be a 2-D array, got shape {z.shape}")
    out = np.full(z.shape, np.nan, dtype=np.float32)
    valid = z > 0
    out[valid] = (fx * baseline_m * 1000.0) / z[valid].astype(np.float64)
    return out


def confidence_from_map(conf_map: np.ndarray) -> np.ndarray:
    """DepthAI v3's confidence map (uint8, 255 = most confident, 0 = least) as float32 in [0, 1], 1 = best.

    v2 had the inverse scale (0 = best); since v3 ``setConfidenceThreshold`` keeps values above it.
    """
    return (np.asarray(conf_map, dtype=np.float32) / 255.0).astype(np.float32)


def camera_for_frame(rgb: dai.ImgFrame, fallback: PinholeCamera) -> PinholeCamera:
    """The intrinsics that apply to this colour frame.

    A device frame carries its own ``ImgTransformation`` (the crop/scale the ISP really applied);
    it wins when valid and of the frame's size. Otherwise the calibration-derived camera is used,
    scaled to the frame if the device delivered another size than requested.
    """
    w, h = rgb.getWidth(), rgb.getHeight()
    t = rgb.getTransformation()
    if t.isValid() and tuple(t.getSize()) == (w, h):
        k = np.asarray(t.getIntrinsicMatrix(), dtype=np.float64)
        if np.all(np.isfinite(k)) and k[0, 0] > 0 and k[1, 1] > 0:
            return PinholeCamera(fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], width=w, height=h)
    if (w, h) != (fallback.width, fallback.height):
        return fallback.scaled(w, h)
    return fallback


def frame_from_messages(
    rgb: dai.ImgFrame,
    depth: dai.ImgFrame,
    conf: dai.ImgFrame | None,
    camera: PinholeCamera,
    baseline_m: float,
    meta: dict | None = None,
) -> Frame:
    """One :class:`Frame` from a synchronised colour frame and aligned depth (uint16 mm).

    Depth aligned by the device normally has the colour size; if not (RVC2 scales on some
    configurations) a frame of the same aspect ratio is resized with nearest neighbour so that no
    depth is invented between surfaces, and one of another aspect raises :class:`DepthNotRegistered`
    (it covers another field of view). Confidence is 0 where depth is invalid.
    """
    image = rgb.getCvFrame()
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    image = np.ascontiguousarray(image[:, :, :3], dtype=np.uint8)
    h, w = image.shape[:2]
    cam = camera_for_frame(rgb, camera)
    depth_mm = depth.getFrame()
    if depth_mm.dtype != np.uint16:
        raise SourceError(f"OAK depth must be uint16 millimetres (RAW16), got {depth_mm.dtype}")
    if depth_mm.shape != (h, w):
        check_registered("depth", depth_mm.shape, w, h)
        depth_mm = cv2.resize(depth_mm, (w, h), interpolation=cv2.INTER_NEAREST)
    disparity = depth_to_disparity(depth_mm, cam.fx, baseline_m)
    confidence = None
    if conf is not None:
        c = conf.getFrame()
        if c.shape != (h, w):
            check_registered("confidence map", c.shape, w, h)
            c = cv2.resize(c, (w, h), interpolation=cv2.INTER_NEAREST)
        confidence = confidence_from_map(c)
        confidence[np.isnan(disparity)] = 0.0
    # Host-synced time (DepthAI maps the device clock onto the host's steady clock), so frames of
    # several devices and host events share one time base; the device clock restarts at boot.
    stamp = rgb.getTimestamp()
    info = {"source": "oak", "sequence": int(rgb.getSequenceNum()), "depth_unit": "mm"}
    info.update(meta or {})
    return Frame(
        image=image,
        disparity=disparity,
        camera=cam,
        baseline_m=baseline_m,
        confidence=confidence,
        timestamp=stamp.total_seconds(),
        meta=info,
    )


def read_group(queue: dai.MessageQueue, timeout_s: float, device: dai.Device | None = None) -> dai.MessageGroup:
    """The next message of a DepthAI output queue, with DepthAI's failures mapped to typed errors.

    A closed queue (``MessageQueue.QueueException``), an XLink ``RuntimeError`` or, after a wait
    without message, a closed device means the device went away (:class:`SourceDisconnected`:
    reopen). No message within ``timeout_s`` from a device that is still there is a
    :class:`SourceTimeout` (covered lens, overloaded bus: wait, do not reboot the device).
    """
    try:
        msg = queue.get(timedelta(seconds=timeout_s))
    except dai.MessageQueue.QueueException as exc:
        raise SourceDisconnected(f"the OAK stopped sending ({exc}); check the USB cable and reopen the source") from exc
    except RuntimeError as exc:
        raise SourceDisconnected(f"the OAK connection failed ({exc}); check the USB cable and reopen the source") from exc
    if msg is None:
        if queue.isClosed() or (device is not None and device.isClosed()):
            raise SourceDisconnected("the OAK closed its connection (unplugged or crashed); check the USB "
                                     "cable and reopen the source")
        raise SourceTimeout(f"no frame from the OAK within {timeout_s:.1f} s; it is still connected: is it "
                            "overloaded (lower fps or size) or is the USB link saturated?")
    if not isinstance(msg, dai.MessageGroup):
        raise SourceError(f"the OAK pipeline sent a {type(msg).__name__}, expected a synchronised MessageGroup")
    return msg
