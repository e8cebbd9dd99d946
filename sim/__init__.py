"""The simulated three-camera rig: analytic scenes with ground truth, the sensor model and a Source.

``scenario(...)`` gives (frame, truth, clicks) for evaluation; ``open_source("sim:poster?distance=6")``
streams frames (see sim.source). Nothing heavy is imported until used.
"""

from __future__ import annotations

from sim.scenario import scenario, simulate_frame
from sim.scenes import BOARD_M, MOUNTS, SCENES, STANDOFFS_M, TARGETS, SceneError, SceneParams
from sim.sensor import SensorError, SensorModel
from sim.textures import LIGHTING
from sim.truth import ClickModel, Truth

__all__ = [
    "BOARD_M",
    "MOUNTS",
    "STANDOFFS_M",
    "LIGHTING",
    "SCENES",
    "TARGETS",
    "ClickModel",
    "SceneError",
    "SceneParams",
    "SensorError",
    "SensorModel",
    "Truth",
    "scenario",
    "simulate_frame",
]
