"""Luxonis OAK cameras over DepthAI v3: stereo depth aligned to the colour camera (or the left mono).

The device computes depth on board and aligns it to the output image; this package turns each
synchronised image + depth pair into a :class:`measure.Frame` whose disparity is expressed at the
output camera's focal length (docs/design.md "Shared types": ``d = fx * B / Z - doffs``, doffs = 0).

DepthAI v3 semantics this package relies on (checked against the 3.12 stubs and depthai-core's v3
examples; verified without hardware only):

- sockets come from the device (``getConnectedCameraFeatures``) and the stereo pair from its
  calibration (``getStereoLeftCameraId``), not fixed CAM_A/B/C: a model without a colour camera
  delivers the rectified left image with depth aligned to it (:func:`choose_sockets`);
- the confidence map is 255 = most confident and ``setConfidenceThreshold(t)`` keeps pixels whose
  confidence is above ``t``. 55 is only a bare ``StereoDepthConfig``'s value: the presets set their
  own (DEFAULT: 15 on RVC2, 20 on RVC4; ACCURACY: 55 and 97). The map is delivered only when it is
  registered to the image: aligned to the rectified left (``align=left``). DepthAI cannot align it
  to colour (RVC2 leaves it in the rectified frame; RVC4's ImageAlign warps a RAW8 map without any
  depth-dependent shift);
- ``StereoDepth.build(..., preset)`` applies the preset; only options the user set override it,
  except the post-processing that would bias a measurement (temporal filter, decimation, hole
  filling, spatial filter), which is off whatever the preset (:func:`measurement_filters`);
- the pipeline's automatic calibration (ON_START by default in 3.12, may write a calibration to the
  device) is OFF unless ``auto_calibration=on_start|continuous`` is asked for;
- the output queue holds one message and drops older ones (newest wins: no queued latency), and
  ``Frame.timestamp`` is the host-synced ``getTimestamp`` (host monotonic clock), not the device clock.

The conversions are plain functions of DepthAI messages and calibration objects so that tests can
drive them with host-built ``dai.CalibrationHandler`` and ``dai.ImgFrame`` objects; only
:meth:`OakSource.open` needs a device. Modules: ``config`` (options and spec), ``pipeline`` (sockets and
wiring), ``calibration`` (intrinsics, baseline), ``frames`` (message conversion), ``source``.
"""

from __future__ import annotations

import os

# DepthAI prints a USB banner on import and searches 11 s for a device by default: keep the CLI
# quiet and make "no device" fail fast. Both must be set before the first import of depthai, which
# every module of this package does after this package's __init__ has run.
os.environ.setdefault("DEPTHAI_LEVEL", "error")
os.environ.setdefault("DEPTHAI_SEARCH_TIMEOUT", "1000")

from device.sources.oak.calibration import baseline_m_from_calibration, intrinsics_from_calibration, output_camera  # noqa: E402
from device.sources.oak.config import ALIGNS, AUTO_CALIBRATION, COLOR_SOCKET, PRESETS, OakConfig, config_from_spec  # noqa: E402
from device.sources.oak.frames import (  # noqa: E402
    DepthNotRegistered,
    camera_for_frame,
    check_registered,
    confidence_from_map,
    depth_to_disparity,
    frame_from_messages,
    read_group,
)
from device.sources.oak.pipeline import (  # noqa: E402
    OakPipeline,
    Sockets,
    build_pipeline,
    choose_sockets,
    configure_stereo,
    depth_settings,
    measurement_filters,
    preset_mode,
)
from device.sources.oak.source import PLUG_IN_HINT, UDEV_HINT, UDEV_RULE, OakSource, find_device  # noqa: E402

__all__ = [
    "ALIGNS",
    "AUTO_CALIBRATION",
    "COLOR_SOCKET",
    "DepthNotRegistered",
    "PLUG_IN_HINT",
    "PRESETS",
    "UDEV_HINT",
    "UDEV_RULE",
    "OakConfig",
    "OakPipeline",
    "OakSource",
    "Sockets",
    "baseline_m_from_calibration",
    "build_pipeline",
    "camera_for_frame",
    "check_registered",
    "choose_sockets",
    "confidence_from_map",
    "config_from_spec",
    "configure_stereo",
    "depth_settings",
    "depth_to_disparity",
    "find_device",
    "frame_from_messages",
    "intrinsics_from_calibration",
    "measurement_filters",
    "output_camera",
    "preset_mode",
    "read_group",
]
