"""Rendered-stereo mode: ray-cast a rectified left/right pair of the textured scene and run OpenCV SGBM.

This exercises the V4L2 stereo pipeline (device/sources/sgbm.py) end to end without hardware, against exact
ground truth. The pair is the reference camera (left) and a camera ``model.baseline_wide_m`` to its
right with the same intrinsics and orientation, so the true disparity is ``fx * B / Z``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from measure import Frame

from sim.scenario import noisy_image
from sim.scenes import SceneParams, get_view
from sim.sensor import SensorModel, _occluded
from sim.textures import LIGHTING
from sim.truth import Truth


def stereo_pair(params: SceneParams, model: SensorModel, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Left (reference) and right BGR images with independent image noise."""
    sigma = LIGHTING[model.lighting].image_noise
    left = noisy_image(get_view(params).renders[model.lighting], sigma, rng)
    right = noisy_image(get_view(params, model.baseline_wide_m).renders[model.lighting], sigma, rng)
    return left, right


def true_disparity(params: SceneParams, model: SensorModel) -> np.ndarray:
    """Ground-truth disparity (px) of the left image, NaN where nothing is hit."""
    view = get_view(params)
    return (view.camera.fx * model.baseline_wide_m / view.depth).astype(np.float32)


def stereo_frame(
    params: SceneParams, model: SensorModel, rng: np.random.Generator, *, target: str | None = None,
    meta: dict[str, Any] | None = None, sgbm: Any = None,
) -> tuple[Frame, Truth]:
    """A frame whose disparity comes from real SGBM on the rendered pair (``sgbm``: a device.sources.sgbm.SGBMConfig)."""
    from device.sources.sgbm import SGBMConfig, compute_disparity, round_up_disparities

    view = get_view(params)
    truth = view.truth(target)
    gt = true_disparity(params, model)
    if sgbm is None:
        sgbm = SGBMConfig(num_disparities=round_up_disparities(int(np.nanmax(gt) * 1.25) + 8), lr_confidence=True)
    left, right = stereo_pair(params, model, rng)
    disparity, confidence = compute_disparity(left, right, sgbm)
    frame = Frame(
        image=left,
        disparity=disparity.astype(np.float32),
        camera=view.camera,
        baseline_m=model.baseline_wide_m,
        doffs=0.0,
        confidence=confidence.astype(np.float32),
        meta={"source": "sim", "mode": "stereo", "scene": params.scene, "lighting": model.lighting,
              "truth": truth, **(meta or {})},
    )
    return frame, truth


def stereo_error(disparity: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """SGBM disparity against ground truth on pixels visible to both cameras.

    density: share of those pixels SGBM matched; within_1px / within_2px: share of the matched ones
    whose error is at most 1 / 2 px; median_abs_px: median absolute error (px).
    """
    visible = np.isfinite(gt) & ~_occluded(gt, +1, int(np.ceil(np.nanmax(gt) - np.nanmin(gt))) + 1)
    matched = visible & np.isfinite(disparity)
    err = np.abs(disparity[matched] - gt[matched])
    return {
        "density": float(matched.sum() / max(visible.sum(), 1)),
        "within_1px": float(np.mean(err <= 1.0)) if err.size else 0.0,
        "within_2px": float(np.mean(err <= 2.0)) if err.size else 0.0,
        "median_abs_px": float(np.median(err)) if err.size else float("nan"),
    }
