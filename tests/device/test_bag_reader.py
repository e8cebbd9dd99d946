"""`bag:` reading: opening from the index only (ROS 1 index, MCAP message indexes, sqlite3), an MCAP without
indexes, and the summary `depthruler replay BAG` prints."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from bag_writers import (
    N_FRAMES,
    PERIOD,
    T0,
    Capture,
    depth_array,
    image_msg,
    info_msg,
    make_capture,
    read_all,
    write_ros_bag,
    write_timed_bag,
    write_viewer_bag,
)
from device.sources.bag import BagReader, summarize_bag


@pytest.fixture(scope="module")
def capture() -> Capture:
    return make_capture()


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
