"""The simulated three-camera rig: analytic scenes with ground truth, the sensor model and a Source.

``scenario(...)`` gives (frame, truth, clicks) for evaluation; ``open_source("sim:poster?distance=6")``
streams frames (see sim.source). Nothing heavy is imported until used.
"""

from __future__ import annotations

from .scenario import scenario, simulate_frame
from .scenes import BOARD_M, MOUNTS, SCENES, STANDOFFS_M, TARGETS, SceneError, SceneParams
from .sensor import SensorError, SensorModel
from .textures import LIGHTING
from .truth import ClickModel, Truth

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
