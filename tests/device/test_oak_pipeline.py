"""OAK pipeline without a device: presets, stereo settings over the preset, sockets from the device, and the
node wiring on both platforms (nodes mocked to the installed depthai classes)."""

from __future__ import annotations

import pytest

from device import SourceError, SourceNotFound
from device.sources.oak import (
    PRESETS,
    OakConfig,
    build_pipeline,
    Sockets,
    choose_sockets,
    configure_stereo,
    depth_settings,
    preset_mode,
)

import depthai as dai  # noqa: E402  (device.sources.oak has set DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT)

from oak_helpers import FIXTURE, A, B, C, Wiring, default_preset_config, features as _features  # noqa: E402


def test_every_preset_maps_to_its_depthai_enum():
    modes = {name: preset_mode(name) for name in PRESETS}
    assert {m.name for m in modes.values()} == set(PRESETS)
    assert len({int(m.value) for m in modes.values()}) == len(PRESETS)
    assert set(dai.node.StereoDepth.PresetMode.__members__) == set(PRESETS)


def test_stereo_config_applied_to_depthai_config_object():
    sdc = configure_stereo(dai.StereoDepthConfig(), OakConfig(subpixel=True, lr_check=False,
                                                              extended_disparity=True, confidence_threshold=180))
    assert sdc.getSubpixel() is True and sdc.getLeftRightCheck() is False and sdc.getExtendedDisparity() is True
    assert sdc.getConfidenceThreshold() == 180
    assert sdc.getDepthUnit() == dai.LengthUnit.MILLIMETER


def test_unset_options_keep_what_the_preset_chose():
    """Defect 2: build(..., preset) fills the config; options the user did not set must not override it."""
    preset_like = dai.StereoDepthConfig()
    preset_like.setExtendedDisparity(True)  # e.g. what the depth-align example's preset + setting gives
    preset_like.setSubpixel(True)
    preset_like.setSubpixelFractionalBits(5)
    preset_like.setLeftRightCheck(False)
    preset_like.setConfidenceThreshold(15)
    out = configure_stereo(preset_like, OakConfig())
    assert out.getExtendedDisparity() is True and out.getSubpixel() is True and out.getLeftRightCheck() is False
    assert out.getSubpixelFractionalBits() == 5 and out.getConfidenceThreshold() == 15
    assert out.getDepthUnit() == dai.LengthUnit.MILLIMETER


COLOR, MONO = dai.CameraSensorType.COLOR, dai.CameraSensorType.MONO
D = dai.CameraBoardSocket.CAM_D


def test_sockets_come_from_the_device_and_its_calibration():
    """Defect 7: sockets are read from the device, not assumed."""
    calib = dai.CalibrationHandler(str(FIXTURE))  # stereo left CAM_B, right CAM_C
    oak_d = _features((A, COLOR, "IMX378"), (B, MONO, "OV9282"), (C, MONO, "OV9282"))
    assert choose_sockets(oak_d, calib) == Sockets(left=B, right=C, color=A)
    assert choose_sockets(oak_d, calib, "left") == Sockets(left=B, right=C, color=None)
    # A model without a colour camera aligns to the rectified left image.
    no_colour = _features((B, MONO, "OV9282"), (C, MONO, "OV9282"))
    assert choose_sockets(no_colour, calib) == Sockets(left=B, right=C, color=None)
    with pytest.raises(SourceError, match="no colour camera"):
        choose_sockets(no_colour, calib, "color")
    # Without stereo extrinsics: the two mono cameras, whatever their sockets; colour elsewhere than CAM_A.
    odd = _features((D, COLOR, "IMX462"), (B, MONO, "OV9282"), (C, MONO, "OV9282"))
    assert choose_sockets(odd, dai.CalibrationHandler()) == Sockets(left=B, right=C, color=D)
    with pytest.raises(SourceNotFound, match="no stereo pair"):
        choose_sockets(_features((A, COLOR, "IMX378")), dai.CalibrationHandler())


def _wire(platform, sockets: Sockets, config: OakConfig = OakConfig()) -> Wiring:
    w = Wiring()
    build_pipeline(w.pipeline, platform, sockets, config)
    return w


@pytest.mark.parametrize("platform", [dai.Platform.RVC2, dai.Platform.RVC4])
def test_wiring_colour_aligned(platform):
    """Defects 2, 3, 5, 8 and 7 on both platforms, through build_pipeline."""
    w = _wire(platform, Sockets(left=B, right=C, color=A))
    cams = w.nodes["Camera"]
    assert [c.build.call_args.args[0] for c in cams] == [B, C, A]
    stereo = w.nodes["StereoDepth"][0]
    assert stereo.build.call_args.args[2] == dai.node.StereoDepth.PresetMode.DEFAULT
    # 2: nothing the user left unset overrides the preset
    for setter in ("setExtendedDisparity", "setSubpixel", "setLeftRightCheck", "setSubpixelFractionalBits"):
        getattr(stereo, setter).assert_not_called()
        getattr(stereo.initialConfig, setter).assert_not_called()
    stereo.initialConfig.setDepthUnit.assert_called_once_with(dai.LengthUnit.MILLIMETER)
    # 5: automatic calibration explicitly off
    w.pipeline.setAutoCalibrationMode.assert_called_once_with(dai.Pipeline.AutoCalibrationMode.OFF)
    # The calibrated baseline both for depth and for aligning it to colour (DepthAI's alignment
    # default is the board drawing's).
    stereo.setDisparityToDepthUseSpecTranslation.assert_called_once_with(False)
    stereo.setDepthAlignmentUseSpecTranslation.assert_called_once_with(False)
    # 8: newest wins
    w.nodes["Sync"][0].out.createOutputQueue.assert_called_once_with(maxSize=1, blocking=False)
    # 3: no confidence map is delivered when it cannot be registered to colour
    assert not any(src.endswith("confidenceMap") for src, _ in w.links)
    assert w.into("sync.conf") == set()
    assert w.into("sync.rgb") == {"Camera2.out"}
    if platform == dai.Platform.RVC4:
        assert w.into("sync.depth") == {"ImageAlign0.outputAligned"}
        assert w.into("ImageAlign0.input") == {"StereoDepth0.depth"}
        assert w.into("ImageAlign0.inputAlignTo") == {"Camera2.out"}
        assert len(w.nodes["ImageAlign"]) == 1
    else:
        assert w.into("sync.depth") == {"StereoDepth0.depth"}
        assert w.into("StereoDepth0.inputAlignTo") == {"Camera2.out"}
        assert "ImageAlign" not in w.nodes


@pytest.mark.parametrize("platform", [dai.Platform.RVC2, dai.Platform.RVC4])
def test_wiring_left_aligned_delivers_registered_confidence(platform):
    cfg = OakConfig(preset="HIGH_DETAIL", extended_disparity=True, subpixel=False, confidence_threshold=100,
                    auto_calibration="on_start")
    w = _wire(platform, Sockets(left=B, right=C, color=None), cfg)
    stereo = w.nodes["StereoDepth"][0]
    assert len(w.nodes["Camera"]) == 2
    stereo.setDepthAlign.assert_called_once_with(dai.StereoDepthConfig.AlgorithmControl.DepthAlign.RECTIFIED_LEFT)
    assert w.into("sync.rgb") == {"StereoDepth0.rectifiedLeft"}
    assert w.into("sync.depth") == {"StereoDepth0.depth"}
    assert w.into("sync.conf") == {"StereoDepth0.confidenceMap"}
    stereo.initialConfig.setExtendedDisparity.assert_called_once_with(True)
    stereo.initialConfig.setSubpixel.assert_called_once_with(False)
    stereo.initialConfig.setLeftRightCheck.assert_not_called()
    stereo.initialConfig.setConfidenceThreshold.assert_called_once_with(100)
    w.pipeline.setAutoCalibrationMode.assert_called_once_with(dai.Pipeline.AutoCalibrationMode.ON_START)


def test_pipeline_default_auto_calibration_is_on_start():
    """Why defect 5 needs the explicit call: DepthAI 3.12's own default would recalibrate at start."""
    assert dai.Pipeline(False).getAutoCalibrationMode() == dai.Pipeline.AutoCalibrationMode.ON_START


MEDIAN = dai.StereoDepthConfig.MedianFilter


@pytest.mark.parametrize("platform", [dai.Platform.RVC2, dai.Platform.RVC4])
def test_measurement_filters_whatever_the_preset(platform):
    """The DEFAULT preset's temporal filter, decimation, hole filling and spatial filter are off on
    the real config the node carries; what removes rather than invents depth keeps the preset's value."""
    preset = default_preset_config(platform)
    if platform == dai.Platform.RVC2:  # what DEFAULT brings on RVC2: all four on
        pp = preset.postProcessing
        assert pp.temporalFilter.enable and pp.temporalFilter.alpha == pytest.approx(0.5)
        assert pp.decimationFilter.decimationFactor == 2 and pp.holeFilling.enable and pp.spatialFilter.enable
    w = Wiring(preset)
    wired = build_pipeline(w.pipeline, platform, Sockets(left=B, right=C, color=A), OakConfig())
    cfg = w.nodes["StereoDepth"][0].initialConfig
    assert cfg is preset
    pp = cfg.postProcessing
    assert pp.temporalFilter.enable is False
    assert pp.decimationFilter.decimationFactor == 1
    assert pp.holeFilling.enable is False
    assert pp.spatialFilter.enable is False
    rvc2 = platform == dai.Platform.RVC2
    assert cfg.getMedianFilter() == (MEDIAN.KERNEL_7x7 if rvc2 else MEDIAN.KERNEL_5x5)
    assert cfg.getConfidenceThreshold() == (15 if rvc2 else 20)
    assert pp.speckleFilter.enable is True and cfg.getDepthUnit() == dai.LengthUnit.MILLIMETER
    assert wired.depth == {
        "postprocessing": "measurement", "temporal_filter": False, "decimation": 1, "hole_filling": False,
        "spatial_filter": False, "median": "KERNEL_7x7" if rvc2 else "KERNEL_5x5", "speckle_filter": True,
        "confidence_threshold": 15 if rvc2 else 20, "lr_check": rvc2, "subpixel": True,
        "extended_disparity": not rvc2, "baseline": "calibrated (depth and alignment)",
    }
    assert wired.queue is w.nodes["Sync"][0].out.createOutputQueue.return_value


def test_bare_config_fills_holes_and_the_measurement_config_does_not():
    """Even without a preset depthai's own config fills holes (and other presets turn on the rest)."""
    bare = dai.StereoDepthConfig()
    assert bare.postProcessing.holeFilling.enable is True
    out = configure_stereo(bare, OakConfig(preset="HIGH_DETAIL", confidence_threshold=200))
    assert out.postProcessing.holeFilling.enable is False and out.getConfidenceThreshold() == 200
    assert depth_settings(out)["hole_filling"] is False
