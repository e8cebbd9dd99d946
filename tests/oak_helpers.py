"""Host-built DepthAI objects for the OAK tests (no device): the calibration fixture and ImgFrames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import device.sources.oak  # noqa: F401  (sets DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT before depthai loads)
import depthai as dai  # noqa: E402

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "oak_calib.json"
A, B, C = dai.CameraBoardSocket.CAM_A, dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C


def fixture_camera(socket: int) -> dict:
    data = json.loads(FIXTURE.read_text())
    return next(cam for sock, cam in data["cameraData"] if sock == socket)


def img(arr: np.ndarray, kind) -> dai.ImgFrame:
    f = dai.ImgFrame()
    f.setCvFrame(arr, kind)
    return f


def default_preset_config(platform: dai.Platform) -> dai.StereoDepthConfig:
    """A ``StereoDepthConfig`` filled the way depthai-core's ``StereoDepth::setRvc2ProfilePreset`` /
    ``setRvc4ProfilePreset`` fill the node's initialConfig for ``PresetMode.DEFAULT`` (the fields
    the measurement cares about), since a node's own config cannot be built without a device."""
    c = dai.StereoDepthConfig()
    pp = c.postProcessing
    if platform == dai.Platform.RVC2:  # DENSITY, then DEFAULT's own settings
        c.setConfidenceThreshold(15)
        c.setLeftRightCheck(True)
        c.setLeftRightCheckThreshold(10)
        pp.holeFilling.enable = True
        pp.holeFilling.highConfidenceThreshold = 100
        pp.holeFilling.fillConfidenceThreshold = 210
        pp.holeFilling.minValidDisparity = 3
        pp.adaptiveMedianFilter.enable = True
        c.setExtendedDisparity(False)
        c.setSubpixel(True)
        c.setSubpixelFractionalBits(3)
        c.setMedianFilter(dai.StereoDepthConfig.MedianFilter.KERNEL_7x7)
        pp.decimationFilter.decimationFactor = 2
        pp.spatialFilter.enable = True
        pp.spatialFilter.holeFillingRadius = 1
        pp.temporalFilter.enable = True
        pp.temporalFilter.alpha = 0.5
        pp.speckleFilter.enable = True
        pp.speckleFilter.speckleRange = 200
        pp.thresholdFilter.maxRange = 15000
    else:
        c.algorithmControl.enableSwLeftRightCheck = True
        pp.adaptiveMedianFilter.enable = True
        pp.decimationFilter.decimationFactor = 1
        pp.holeFilling.enable = False
        pp.spatialFilter.enable = False
        pp.speckleFilter.enable = True
        pp.speckleFilter.speckleRange = 200
        c.setConfidenceThreshold(20)
        c.setLeftRightCheckThreshold(4)
        c.setMedianFilter(dai.StereoDepthConfig.MedianFilter.KERNEL_5x5)
        c.setExtendedDisparity(True)
        c.setLeftRightCheck(False)
    return c
