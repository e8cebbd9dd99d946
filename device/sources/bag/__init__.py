"""ROS bags as a source: ``bag:PATH[?depth=TOPIC&color=TOPIC&...]`` (read with ``rosbags``, no ROS install).

PATH is a ROS 1 ``.bag`` file, a ROS 2 bag folder (``metadata.yaml`` with MCAP or sqlite3 storage) or a
single ``.mcap`` / ``.db3`` file. Without topic options the layout is recognised (``layout.py``): the
RealSense Viewer, realsense-ros and depthai-ros; ``depth=``/``color=`` (``depth_info=``/``color_info=``)
name the topics of any other bag.

Steps: ``storage`` opens the bag and reads message times from its index; ``reader`` pairs each colour
message with the depth message nearest in time (within ``skew_ms``), reads the calibration and
extrinsics, and decodes a frame only when it is asked for (``messages``); ``undistort`` resamples a
distorted colour image and its depth onto pinhole images (camera_info ``D``); ``geometry`` registers
depth to the colour camera (z-buffered footprint splatting); ``source`` plays the frames in order.

Units: depth in metres (16-bit depth in its depth unit, ROS: mm), times in ns, pixels. Frames carry
disparity ``d = fx * B / Z`` with the colour camera's ``fx`` and the recorded stereo baseline, else
``DEFAULT_BASELINE_M`` or ``?baseline=``; any ``B`` gives back ``Z`` exactly. ``meta["depth_unit_m"]``
and ``meta["disparity_from_depth"]`` say the disparity steps are the depth unit's, not a matcher's.
Why these rules, and the measured opening times: docs/decisions/bag-source.md.
"""

from __future__ import annotations

from device.sources.bag.config import BagConfig, BagOptions
from device.sources.bag.errors import BagError, BagLayoutError, BagNotFound
from device.sources.bag.geometry import MAX_SPLAT_PX, Rigid, align_depth_to_color, pair_by_time
from device.sources.bag.layout import Layout, detect_layout
from device.sources.bag.messages import DEFAULT_ROS_DEPTH_UNIT_M, camera_from_info, decode_color, decode_depth
from device.sources.bag.reader import BagContents, BagReader, summarize_bag
from device.sources.bag.source import BagSource, config_from_spec
from device.sources.bag.storage import BAG_SUFFIXES, is_bag_path, topic_times
from device.sources.bag.undistort import Distortion, distortion_from_info, undistort_maps

__all__ = [
    "BAG_SUFFIXES",
    "DEFAULT_ROS_DEPTH_UNIT_M",
    "MAX_SPLAT_PX",
    "BagConfig",
    "BagContents",
    "BagError",
    "BagLayoutError",
    "BagNotFound",
    "BagOptions",
    "BagReader",
    "BagSource",
    "Distortion",
    "Layout",
    "Rigid",
    "align_depth_to_color",
    "camera_from_info",
    "config_from_spec",
    "decode_color",
    "decode_depth",
    "detect_layout",
    "distortion_from_info",
    "is_bag_path",
    "pair_by_time",
    "summarize_bag",
    "topic_times",
    "undistort_maps",
]
