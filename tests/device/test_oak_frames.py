"""OAK frame conversion without a device: host-built dai.ImgFrame depth, confidence and transformations, and
the output queue's failures as typed errors."""

from __future__ import annotations

from datetime import timedelta
from unittest import mock

import numpy as np
import pytest

from device import SourceDisconnected, SourceError, SourceTimeout
from device.sources.oak import (
    DepthNotRegistered,
    baseline_m_from_calibration,
    camera_for_frame,
    depth_to_disparity,
    frame_from_messages,
    intrinsics_from_calibration,
    read_group,
)

import depthai as dai  # noqa: E402  (device.sources.oak has set DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT)

from oak_helpers import FIXTURE, img  # noqa: E402


def test_depth_frames_convert_to_disparity_at_colour_focal_length():
    calib = dai.CalibrationHandler(str(FIXTURE))
    w, h = 128, 72
    cam = intrinsics_from_calibration(calib, w, h)
    baseline = baseline_m_from_calibration(calib)
    rng = np.random.default_rng(0)
    depth_mm = rng.integers(300, 9000, size=(h // 2, w // 2)).astype(np.uint16)  # half size: resized
    depth_mm[:3, :] = 0  # DepthAI's "no data"
    colour = rng.integers(0, 255, size=(h, w, 3)).astype(np.uint8)
    conf_map = rng.integers(0, 255, size=(h // 2, w // 2)).astype(np.uint8)
    rgb = img(colour, dai.ImgFrame.Type.BGR888i)
    rgb.setTimestamp(timedelta(seconds=12.5))
    rgb.setSequenceNum(7)
    frame = frame_from_messages(rgb, img(depth_mm, dai.ImgFrame.Type.RAW16), img(conf_map, dai.ImgFrame.Type.RAW8),
                                cam, baseline)
    assert frame.image.shape == (h, w, 3) and np.array_equal(frame.image, colour)
    up = np.repeat(np.repeat(depth_mm, 2, axis=0), 2, axis=1)  # nearest-neighbour upsampling
    valid = up > 0
    expected = cam.fx * baseline / (up[valid] / 1000.0)
    assert np.allclose(frame.disparity[valid], expected, rtol=1e-5)
    assert np.isnan(frame.disparity[~valid]).all()
    assert np.allclose(frame.depth()[valid], up[valid] / 1000.0, rtol=1e-5)  # exact round trip to metres
    conf_up = np.repeat(np.repeat(conf_map, 2, axis=0), 2, axis=1)
    assert np.allclose(frame.confidence[valid], conf_up[valid] / 255.0, atol=1e-6)
    assert (frame.confidence[~valid] == 0).all()
    assert frame.timestamp == pytest.approx(12.5) and frame.meta["sequence"] == 7
    # Defect 8: the device clock (restarts at boot) is not the frame time; the host-synced one is.
    rgb.setTimestampDevice(timedelta(seconds=3.25))
    again = frame_from_messages(rgb, img(depth_mm, dai.ImgFrame.Type.RAW16), None, cam, baseline)
    assert again.timestamp == pytest.approx(12.5)
    assert frame.camera == cam and frame.baseline_m == baseline and frame.doffs == 0.0


def test_confidence_map_is_v3_scale_255_is_best():
    """Defect 1: in v3 a confidence of 255 is the most confident pixel (v2 had it the other way round)."""
    calib = dai.CalibrationHandler(str(FIXTURE))
    cam = intrinsics_from_calibration(calib, 4, 2)
    rgb = img(np.zeros((2, 4, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    depth = img(np.full((2, 4), 1000, np.uint16), dai.ImgFrame.Type.RAW16)
    conf = img(np.array([[255, 200, 55, 0], [255, 255, 0, 0]], np.uint8), dai.ImgFrame.Type.RAW8)
    frame = frame_from_messages(rgb, depth, conf, cam, 0.075)
    assert frame.confidence[0].tolist() == pytest.approx([1.0, 200 / 255, 55 / 255, 0.0])
    # The threshold keeps pixels above it; 55 is a bare config's value (the presets set their own).
    assert dai.StereoDepthConfig().getConfidenceThreshold() == 55


def test_depth_to_disparity_known_values():
    d = depth_to_disparity(np.array([[0, 1000, 2000, 500]], np.uint16), fx=800.0, baseline_m=0.075)
    assert np.isnan(d[0, 0])
    assert d[0, 1:] == pytest.approx([60.0, 30.0, 120.0])
    assert d.dtype == np.float32


def test_frame_transformation_wins_over_calibration():
    calib = dai.CalibrationHandler(str(FIXTURE))
    fallback = intrinsics_from_calibration(calib, 128, 72)
    rgb = img(np.zeros((72, 128, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    assert camera_for_frame(rgb, fallback) == fallback
    t = dai.ImgTransformation(256, 144, [[200.0, 0, 128.0], [0, 202.0, 72.0], [0, 0, 1]])
    t.addScale(0.5, 0.5)  # what the ISP did: 256x144 -> 128x72
    rgb.setTransformation(t)
    cam = camera_for_frame(rgb, fallback)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == pytest.approx((100, 101, 64, 36, 128, 72))
    # A frame of another size than requested, without a transformation: scale the fallback.
    other = img(np.zeros((144, 256, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    assert camera_for_frame(other, fallback).fx == pytest.approx(2 * fallback.fx)


def test_timeout_from_a_live_device_is_not_a_disconnect():
    """Defect 4: no frame in time from a device that is still open is a timeout (no reboot);
    the same wait on a closed device is a disconnect."""
    q = dai.MessageQueue("sync", 1, False)
    device = mock.create_autospec(dai.Device, instance=True)
    device.isClosed.return_value = False
    with pytest.raises(SourceTimeout) as err:
        read_group(q, 0.02, device)
    assert not isinstance(err.value, SourceDisconnected)
    device.isClosed.return_value = True
    with pytest.raises(SourceDisconnected, match="closed"):
        read_group(q, 0.02, device)


def test_newest_frame_wins_in_a_one_message_queue():
    """Defect 8: the queue the source reads (maxSize=1, non-blocking, see the wiring test) returns
    the newest message, not the oldest of four."""
    q = dai.MessageQueue("sync", 1, False)
    for seq in range(4):
        g = dai.MessageGroup()
        frame = img(np.zeros((2, 2), np.uint16), dai.ImgFrame.Type.RAW16)
        frame.setSequenceNum(seq)
        g["depth"] = frame
        q.send(g)
    assert read_group(q, 0.1)["depth"].getSequenceNum() == 3


def test_queue_failures_become_typed_errors():
    q = dai.MessageQueue("sync", 4, False)
    with pytest.raises(SourceTimeout, match="no frame"):
        read_group(q, 0.05)
    group = dai.MessageGroup()
    group["depth"] = img(np.ones((4, 4), np.uint16), dai.ImgFrame.Type.RAW16)
    q.send(group)
    assert read_group(q, 0.5)["depth"].getWidth() == 4
    q.close()  # what a pipeline stop or a pulled cable does to the queue
    with pytest.raises(SourceDisconnected, match="USB cable"):
        read_group(q, 0.05)


def test_depth_must_be_millimetres():
    rgb = img(np.zeros((8, 8, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    calib = dai.CalibrationHandler(str(FIXTURE))
    cam = intrinsics_from_calibration(calib, 8, 8)
    with pytest.raises(SourceError, match="uint16"):
        frame_from_messages(rgb, img(np.zeros((8, 8), np.uint8), dai.ImgFrame.Type.RAW8), None, cam, 0.075)


def test_depth_of_another_aspect_is_refused_not_stretched():
    """Mono-sized depth (640x400, 16:10) under a 16:9 colour image covers another field of view:
    stretching it put depth 1/10 of the height away from where it belongs."""
    calib = dai.CalibrationHandler(str(FIXTURE))
    cam = intrinsics_from_calibration(calib, 128, 72)
    rgb = img(np.zeros((72, 128, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    mono_sized = img(np.full((40, 64), 1500, np.uint16), dai.ImgFrame.Type.RAW16)
    with pytest.raises(DepthNotRegistered, match=r"64x40 but the image is 128x72.*align=color.*size=115x72") as err:
        frame_from_messages(rgb, mono_sized, None, cam, 0.075)
    assert isinstance(err.value, SourceError)
    # The same aspect (decimation, or depth output at half size) is still resized onto the image.
    half = frame_from_messages(rgb, img(np.full((36, 64), 1500, np.uint16), dai.ImgFrame.Type.RAW16), None, cam, 0.075)
    assert np.allclose(half.depth(), 1.5)
    # A confidence map of another aspect is refused the same way.
    with pytest.raises(DepthNotRegistered, match="confidence map is 64x40"):
        frame_from_messages(rgb, img(np.full((72, 128), 1500, np.uint16), dai.ImgFrame.Type.RAW16),
                            img(np.zeros((40, 64), np.uint8), dai.ImgFrame.Type.RAW8), cam, 0.075)
