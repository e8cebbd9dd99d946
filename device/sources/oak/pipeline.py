"""The OAK's DepthAI v3 pipeline: which sockets form the stereo pair and the output, the stereo settings
over the preset's, and the node wiring (cameras, StereoDepth, ImageAlign on RVC4, Sync, one-message queue)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta

import depthai as dai

from device.errors import SourceError, SourceNotFound
from device.sources.oak.config import AUTO_CALIBRATION, COLOR_SOCKET, PRESETS, OakConfig

def preset_mode(name: str) -> dai.node.StereoDepth.PresetMode:
    """The DepthAI v3 preset enum for a preset name (see :data:`PRESETS`)."""
    if name not in PRESETS:
        raise SourceError(f"OAK preset {name!r} is unknown; use one of {', '.join(PRESETS)}")
    return getattr(dai.node.StereoDepth.PresetMode, name)


def measurement_filters(stereo_config: dai.StereoDepthConfig) -> dai.StereoDepthConfig:
    """Turn off the post-processing that makes depth unfit for measuring, whatever the preset set.

    - temporal filter off: it blends each frame with the previous ones (alpha 0.5 in the RVC2
      presets), so frames pooled by "measure over N frames" would not be independent;
    - decimation factor 1: decimation changes the depth size the intrinsics must match;
    - hole filling off, and the spatial filter off (its ``holeFillingRadius`` fills too): both invent
      depth in the gaps at object edges, exactly where people click.

    Median, speckle and threshold filters, which remove or smooth but do not invent depth, keep the
    preset's values. Returns the same (mutated) object. The presets' values and why:
    docs/decisions/oak-depth-processing.md.
    """
    pp = stereo_config.postProcessing
    pp.temporalFilter.enable = False
    pp.decimationFilter.decimationFactor = 1
    pp.holeFilling.enable = False
    pp.spatialFilter.enable = False
    return stereo_config


def depth_settings(stereo_config: dai.StereoDepthConfig) -> dict[str, object]:
    """What the device's stereo does to depth, as JSON-ready values, for ``SourceInfo.extra["depth"]``
    (shown by ``/api/source`` and written to a recording's manifest)."""
    pp = stereo_config.postProcessing
    return {
        "postprocessing": "measurement",
        "temporal_filter": bool(pp.temporalFilter.enable),
        "decimation": int(pp.decimationFilter.decimationFactor),
        "hole_filling": bool(pp.holeFilling.enable),
        "spatial_filter": bool(pp.spatialFilter.enable),
        "median": stereo_config.getMedianFilter().name,
        "speckle_filter": bool(pp.speckleFilter.enable),
        "confidence_threshold": int(stereo_config.getConfidenceThreshold()),
        "lr_check": bool(stereo_config.getLeftRightCheck()),
        "subpixel": bool(stereo_config.getSubpixel()),
        "extended_disparity": bool(stereo_config.getExtendedDisparity()),
        "baseline": "calibrated (depth and alignment)",
    }


def configure_stereo(stereo_config: dai.StereoDepthConfig, config: OakConfig) -> dai.StereoDepthConfig:
    """Apply the stereo settings the user set to a ``StereoDepthConfig`` (a node's ``initialConfig``,
    which ``StereoDepth.build(..., preset)`` has already filled from the preset): an option left at
    None keeps the preset's value. The :func:`measurement_filters` are applied whatever the preset.
    Depth unit is forced to millimetres because :func:`depth_to_disparity` expects mm.
    """
    measurement_filters(stereo_config)
    if config.lr_check is not None:
        stereo_config.setLeftRightCheck(config.lr_check)
    if config.subpixel is not None:
        stereo_config.setSubpixel(config.subpixel)
    if config.extended_disparity is not None:
        stereo_config.setExtendedDisparity(config.extended_disparity)
    stereo_config.setDepthUnit(dai.LengthUnit.MILLIMETER)
    if config.confidence_threshold is not None:
        stereo_config.setConfidenceThreshold(config.confidence_threshold)
    return stereo_config


@dataclass(frozen=True)
class OakPipeline:
    """What :func:`build_pipeline` wired: the output queue and the stereo settings in force
    (:func:`depth_settings` of the StereoDepth node's config after the preset and the options)."""

    queue: dai.MessageQueue
    depth: dict[str, object]


@dataclass(frozen=True)
class Sockets:
    """Which cameras of the device to use: the stereo pair and the camera depth is aligned to
    (``color`` None: the rectified left mono image is the output)."""

    left: dai.CameraBoardSocket
    right: dai.CameraBoardSocket
    color: dai.CameraBoardSocket | None


def choose_sockets(features: list[dai.CameraFeatures], calib: dai.CalibrationHandler, align: str = "auto") -> Sockets:
    """The stereo pair and the output camera of a device, from what it reports.

    The stereo pair is the calibration's stereo left/right when both are connected (an OAK-D-LR
    pairs two colour sensors), else the two connected mono cameras. The output is CAM_A when it is
    a connected colour camera outside the pair, else any such colour camera, else (or with
    ``align="left"``) the rectified left image.
    """
    connected = {f.socket: f for f in features}
    pair: tuple[dai.CameraBoardSocket, dai.CameraBoardSocket] | None = None
    try:
        ids = (calib.getStereoLeftCameraId(), calib.getStereoRightCameraId())
        if ids[0] != ids[1] and all(i in connected for i in ids):
            pair = ids
    except RuntimeError:
        pass  # no stereo extrinsics in the calibration: fall back to the mono cameras
    if pair is None:
        monos = sorted((s for s, f in connected.items() if dai.CameraSensorType.MONO in f.supportedTypes), key=int)
        if len(monos) < 2:
            raise SourceNotFound(
                f"this OAK has no stereo pair (cameras: {', '.join(f'{s.name} {connected[s].sensorName}' for s in connected)}); "
                "depthruler needs an OAK-D model"
            )
        pair = (monos[0], monos[1])
    colours = [s for s, f in connected.items() if dai.CameraSensorType.COLOR in f.supportedTypes and s not in pair]
    if align == "color" and not colours:
        raise SourceError("align=color was asked but this OAK has no colour camera outside its stereo pair; "
                          "use align=left (or auto)")
    color = None
    if align != "left" and colours:
        color = COLOR_SOCKET if COLOR_SOCKET in colours else sorted(colours, key=int)[0]
    return Sockets(left=pair[0], right=pair[1], color=color)


def build_pipeline(pipeline: dai.Pipeline, platform: dai.Platform, sockets: Sockets, cfg: OakConfig) -> OakPipeline:
    """Wire the nodes for ``sockets`` on ``pipeline``; return its output queue (one synchronised group:
    ``rgb``, ``depth`` and, aligned to the rectified left only, ``conf``) and the stereo settings."""
    pipeline.setAutoCalibrationMode(AUTO_CALIBRATION[cfg.auto_calibration])
    left = pipeline.create(dai.node.Camera).build(sockets.left)
    right = pipeline.create(dai.node.Camera).build(sockets.right)
    mono = (cfg.mono_width, cfg.mono_height)
    stereo = pipeline.create(dai.node.StereoDepth).build(
        left.requestOutput(mono, fps=cfg.fps), right.requestOutput(mono, fps=cfg.fps), preset_mode(cfg.preset)
    )
    # The calibrated baseline, not the board drawing's, both for depth and for moving depth onto
    # the colour camera (DepthAI's default for the alignment is the drawing's).
    stereo.setDisparityToDepthUseSpecTranslation(False)
    stereo.setDepthAlignmentUseSpecTranslation(False)
    # Only what the user set, on the config build() filled from the preset (the node's own
    # setLeftRightCheck & co. write the same initialConfig).
    configure_stereo(stereo.initialConfig, cfg)
    sync = pipeline.create(dai.node.Sync)
    sync.setSyncThreshold(timedelta(seconds=0.5 / cfg.fps))
    if sockets.color is None:
        # Depth, confidence and image all in the rectified left frame: registered by construction.
        stereo.setDepthAlign(dai.StereoDepthConfig.AlgorithmControl.DepthAlign.RECTIFIED_LEFT)
        stereo.rectifiedLeft.link(sync.inputs["rgb"])
        stereo.depth.link(sync.inputs["depth"])
        if cfg.confidence_map:
            stereo.confidenceMap.link(sync.inputs["conf"])
    else:
        color = pipeline.create(dai.node.Camera).build(sockets.color)
        # Undistorted colour so the pinhole intrinsics hold across the image.
        color_out = color.requestOutput(cfg.size, fps=cfg.fps, enableUndistortion=True)
        color_out.link(sync.inputs["rgb"])
        if platform == dai.Platform.RVC4:
            align = pipeline.create(dai.node.ImageAlign)
            stereo.depth.link(align.input)
            color_out.link(align.inputAlignTo)
            align.outputAligned.link(sync.inputs["depth"])
        else:
            color_out.link(stereo.inputAlignTo)
            stereo.depth.link(sync.inputs["depth"])
        # No confidence map here: it cannot be registered to colour on either platform (device/sources/oak/__init__.py).
    # One message, older ones dropped: the newest frame wins, no queued latency in live view.
    return OakPipeline(queue=sync.out.createOutputQueue(maxSize=1, blocking=False),
                       depth=depth_settings(stereo.initialConfig))
