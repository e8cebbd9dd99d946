"""Host-built DepthAI objects for the OAK tests (no device): the calibration fixture, ImgFrames, camera
features, a preset-filled stereo config and a pipeline whose nodes are spec'd mocks (:class:`Wiring`)."""

from __future__ import annotations

import json
from pathlib import Path
from unittest import mock

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


def features(*cams) -> list:
    out = []
    for socket, kind, sensor in cams:
        f = dai.CameraFeatures()
        f.socket, f.supportedTypes, f.sensorName = socket, [kind], sensor
        out.append(f)
    return out


class Wiring:
    """A dai.Pipeline whose nodes are mocks restricted to the installed classes' attributes.

    ``create_autospec`` restricts methods; pybind properties (outputs, inputs, initialConfig) come
    out unrestricted, so they are set here to spec'd mocks of their real types, after checking
    that the real class has them; ``initial_config`` (a real ``dai.StereoDepthConfig``) replaces the
    StereoDepth node's mock config. Every ``Output.link(Input)`` is recorded as (output, input) labels.
    """

    PROPS = {
        dai.node.StereoDepth: {"depth": dai.Node.Output, "confidenceMap": dai.Node.Output,
                               "rectifiedLeft": dai.Node.Output, "disparity": dai.Node.Output,
                               "inputAlignTo": dai.Node.Input, "initialConfig": dai.StereoDepthConfig},
        dai.node.ImageAlign: {"input": dai.Node.Input, "inputAlignTo": dai.Node.Input,
                              "outputAligned": dai.Node.Output},
        dai.node.Sync: {"out": dai.Node.Output},
        dai.node.Camera: {},
    }

    def __init__(self, initial_config: dai.StereoDepthConfig | None = None) -> None:
        self.initial_config = initial_config
        self.links: list[tuple[str, str]] = []
        self.nodes: dict[str, list] = {}
        self.pipeline = mock.create_autospec(dai.Pipeline, instance=True)
        self.pipeline.create.side_effect = self._create

    def _output(self, label: str):
        out = mock.create_autospec(dai.Node.Output, instance=True)
        out.link.side_effect = lambda inp: self.links.append((label, inp._label))
        return out

    def _input(self, label: str):
        inp = mock.create_autospec(dai.Node.Input, instance=True)
        inp._label = label
        return inp

    def _create(self, cls):
        assert cls in self.PROPS, f"unexpected node {cls}"
        name = cls.__name__
        label = f"{name}{len(self.nodes.get(name, []))}"
        node = mock.create_autospec(cls, instance=True)
        if hasattr(cls, "build"):
            node.build.return_value = node
        for prop, kind in self.PROPS[cls].items():
            assert hasattr(cls, prop), f"{name}.{prop} does not exist in depthai {dai.__version__}"
            if kind is dai.Node.Output:
                setattr(node, prop, self._output(f"{label}.{prop}"))
            elif kind is dai.Node.Input:
                setattr(node, prop, self._input(f"{label}.{prop}"))
            else:
                setattr(node, prop, mock.create_autospec(kind, instance=True))
        if cls is dai.node.StereoDepth and self.initial_config is not None:
            node.initialConfig = self.initial_config
        if cls is dai.node.Camera:
            node.requestOutput.side_effect = lambda *a, **k: self._output(f"{label}.out")
        if cls is dai.node.Sync:
            node.inputs = {k: self._input(f"sync.{k}") for k in ("rgb", "depth", "conf")}
        self.nodes.setdefault(name, []).append(node)
        return node

    def into(self, target: str) -> set[str]:
        return {src for src, dst in self.links if dst == target}
