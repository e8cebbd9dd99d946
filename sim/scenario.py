"""Simulated frames with ground truth and human clicks: what the evaluation and the sim source consume."""

from __future__ import annotations

import time
from dataclasses import dataclass, fields
from functools import lru_cache
from typing import Any

import numpy as np

from measure import Frame

from device.base import REBUILD_IMAGE

from sim.scenes import BOARD_M, STANDOFFS_M, SceneParams, View, get_view, resolve_target
from sim.sensor import SensorError, SensorModel, get_profile, sense
from sim.textures import LIGHTING
from sim.truth import ClickModel, Truth

SENSOR_FIELDS = frozenset(f.name for f in fields(SensorModel))


@lru_cache(maxsize=8)
def _image_noise(height: int, width: int, sigma: float) -> np.ndarray:
    """A fixed sheet of Gaussian image noise (int16) a little larger than the image; frames crop it at
    random offsets, which looks like fresh sensor noise at the cost of one addition."""
    rng = np.random.default_rng(987654321)
    sheet = np.rint(rng.normal(0.0, sigma, (height + 32, width + 32, 3))).astype(np.int16)
    sheet.setflags(write=False)
    return sheet


@dataclass(frozen=True, eq=False)
class NoisyImage:
    """A simulated colour image as it is made: ``render`` (uint8 BGR) plus the crop at ``(oy, ox)`` of
    the fixed noise sheet of ``sigma`` grey levels, saturated; calling it makes the image, bit for
    bit the same on every call (what ``meta[REBUILD_IMAGE]`` holds)."""

    render: np.ndarray
    sigma: float
    oy: int = 0
    ox: int = 0

    def __call__(self) -> np.ndarray:
        import cv2

        if self.sigma <= 0:
            return self.render.copy()
        h, w = self.render.shape[:2]
        sheet = _image_noise(h, w, float(self.sigma))
        return cv2.add(self.render, sheet[self.oy : self.oy + h, self.ox : self.ox + w], dtype=cv2.CV_8U)


def image_noise(render: np.ndarray, sigma: float, rng: np.random.Generator) -> NoisyImage:
    """How to make ``render`` plus image-sensor noise of ``sigma`` grey levels: the sheet offset
    drawn from ``rng`` (nothing drawn when ``sigma`` is 0)."""
    if sigma <= 0:
        return NoisyImage(render, 0.0)
    oy, ox = (int(v) for v in rng.integers(0, 33, 2))
    return NoisyImage(render, float(sigma), oy, ox)


def noisy_image(render: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``render`` (uint8 BGR) plus image-sensor noise of ``sigma`` grey levels, saturated to uint8."""
    return image_noise(render, sigma, rng)()


def make_model(lighting: str = "indoor", profile: str = "stress", **overrides: Any) -> SensorModel:
    """A SensorModel for ``lighting`` and ``profile`` (sim.sensor.PROFILES) with the named fields
    overridden (None = the profile's value); unknown names raise SensorError."""
    unknown = sorted(set(overrides) - SENSOR_FIELDS)
    if unknown:
        raise SensorError(f"unknown sensor parameter(s) {', '.join(unknown)}; use any of {', '.join(sorted(SENSOR_FIELDS))}")
    fields_ = dict(get_profile(profile).sensor)
    fields_.update((k, v) for k, v in overrides.items() if v is not None)
    return SensorModel(lighting=lighting, **fields_)


def simulate_frame(
    params: SceneParams, model: SensorModel, rng: np.random.Generator, *, target: str | None = None,
    timestamp: float | None = None, meta: dict[str, Any] | None = None, rebuild_image: bool = False,
) -> tuple[Frame, Truth]:
    """One frame of the rig looking at the scene, with the truth of ``target`` in ``meta["truth"]``
    (``rebuild_image``: see :func:`frame_from_view`)."""
    view = get_view(params)
    truth = view.truth(target)
    meta = {"source": "sim", "scene": params.scene, "lighting": model.lighting, "truth": truth, **(meta or {})}
    return frame_from_view(view, model, rng, timestamp=timestamp, meta=meta, rebuild_image=rebuild_image), truth


def frame_from_view(view: View, model: SensorModel, rng: np.random.Generator, *, timestamp: float | None = None,
                    meta: dict[str, Any] | None = None, rebuild_image: bool = False) -> Frame:
    """One frame of the rig looking at ``view``: sensed disparity, confidence and a noisy colour image;
    ``rebuild_image``: ``meta[REBUILD_IMAGE]`` holds the :class:`NoisyImage` that makes the image again,
    so that a holder of many live frames can drop their images (the live source sets it)."""
    out = sense(view, model, rng)
    recipe = image_noise(view.renders[model.lighting], LIGHTING[model.lighting].image_noise, rng)
    image = recipe()
    meta = dict(meta or {"source": "sim"})
    if out.offset_px:  # the truth of the frame's calibration error, for studies that split it off
        meta["calibration_offset_px"] = out.offset_px
    if rebuild_image:
        meta[REBUILD_IMAGE] = recipe
    return Frame(
        image=image,
        disparity=out.disparity,
        camera=view.camera,
        baseline_m=model.baseline_wide_m,
        doffs=0.0,
        confidence=out.confidence,
        timestamp=time.time() if timestamp is None else timestamp,
        meta=meta,
    )


def scenario(
    scene: str = "poster",
    *,
    target: str | None = None,
    distance_m: float = 4.0,
    lighting: str = "indoor",
    profile: str = "stress",
    contention: float | None = None,
    quantization: float | None = None,
    seed: int = 0,
    width: int = 1280,
    height: int = 720,
    yaw_deg: float = 0.0,
    roll_deg: float = 0.0,
    clicks: ClickModel | None = None,
    mount: str | None = None,
    board_m: tuple[float, float] = BOARD_M,
    standoff_m: float | None = None,
    **sensor_overrides: Any,
) -> tuple[Frame, Truth, tuple[tuple[float, float], tuple[float, float]]]:
    """A simulated frame, its ground truth and a person's two clicks near the target's end points.

    The geometry is cached per (scene, distance, pose, size, poster mount): ``seed`` changes the sensor
    noise, outliers, holes and the clicks, and for a poster on its stand (``mount="stand"``, the
    paper's free-standing target board) how far in front of the wall it stands (one of
    ``STANDOFFS_M`` unless ``standoff_m`` is given), so thousands of calls cost little more than the
    noise. ``profile`` ("stress" or "paper", sim.sensor.PROFILES) sets the sensor fields, the click
    model and the poster's mount; ``contention``, ``quantization``, ``clicks`` and ``mount`` override
    it. ``mount="wall"`` glues the poster flat on the wall instead; ``board_m`` is the poster's
    (width, length) in metres (default A0 portrait, an assumption: the paper does not give it). Extra
    keyword arguments override SensorModel fields (e.g. ``noise_px=0.5``, ``outlier_model="baseline"``).
    Raises sim.SceneError / sim.SensorError (both ValueError) with the allowed values on bad input.
    """
    # spawn(3)'s first two children equal spawn(2)'s: adding the stand-off stream left noise and clicks as they were.
    sensor_seq, click_seq, scene_seq = np.random.SeedSequence(seed).spawn(3)
    prof = get_profile(profile)
    clicks = prof.clicks if clicks is None else clicks
    mount = prof.mount if mount is None else mount
    poster: dict[str, Any] = {}
    if scene == "poster":
        if standoff_m is None:  # a poster on the wall has no stand-off: one view, not three
            standoff_m = STANDOFFS_M[int(np.random.default_rng(scene_seq).integers(len(STANDOFFS_M)))] if mount == "stand" else 1.0
        poster = dict(mount=mount, board_w_m=float(board_m[0]), board_l_m=float(board_m[1]), standoff_m=float(standoff_m))
    params = SceneParams(scene=scene, distance_m=float(distance_m), yaw_deg=float(yaw_deg), roll_deg=float(roll_deg),
                         width=int(width), height=int(height), **poster)
    target = resolve_target(scene, target)
    model = make_model(lighting, profile, contention=contention, quantization=quantization, **sensor_overrides)
    frame, truth = simulate_frame(params, model, np.random.default_rng(sensor_seq), target=target,
                                  timestamp=0.0, meta={"seed": seed})
    pts = clicks.clicks(truth, np.random.default_rng(click_seq), params.width, params.height)
    return frame, truth, pts
