"""Ground truth of a simulated frame, and a model of where a person's fingers land on a touch screen."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Truth:
    """What the simulator knows exactly about a frame (docs/design.md "Simulated rig").

    depth_m: H x W true depth Z (m, reference camera), NaN where no surface; p1_m, p2_m: the
    measured target's end points (m, reference camera frame: x right, y down, z forward); p1_px, p2_px:
    their pixels (integer-valued pixel centres, so back-projecting them with depth_m gives p1_m, p2_m);
    length_m = |p1_m - p2_m|; target: e.g. "poster-width"; is_gap: the segment between the end points
    crosses empty space onto the background (doorway, space between boxes).
    """

    depth_m: np.ndarray
    p1_m: tuple[float, float, float]
    p2_m: tuple[float, float, float]
    p1_px: tuple[float, float]
    p2_px: tuple[float, float]
    length_m: float
    target: str
    is_gap: bool

    def summary(self) -> dict:
        """JSON-ready summary without the depth map (what a recording stores)."""
        return {
            "p1_m": list(self.p1_m),
            "p2_m": list(self.p2_m),
            "p1_px": list(self.p1_px),
            "p2_px": list(self.p2_px),
            "length_m": self.length_m,
            "target": self.target,
            "is_gap": self.is_gap,
        }


@dataclass(frozen=True)
class ClickModel:
    """Human clicks near the true end points (pixels of the reference image).

    jitter_px: one-sigma Gaussian scatter of a finger tap around the aimed point;
    off_object_prob: chance that a click lands just beyond the end point (off the object for an object,
    inside the opening for a gap), as happens on a touch screen; off_object_px: how far beyond, at most.
    Off a free-standing object (the poster board on its stand, a person) that is the background behind it.
    """

    jitter_px: float = 2.5
    off_object_prob: float = 0.25
    off_object_px: float = 6.0

    def clicks(
        self, truth: Truth, rng: np.random.Generator, width: int, height: int
    ) -> tuple[tuple[float, float], tuple[float, float]]:
        """Two integer-valued click positions (x, y) inside the image."""
        a, b = np.asarray(truth.p1_px, float), np.asarray(truth.p2_px, float)
        u = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
        # "Beyond the end point" is away from the other end for an object, towards it for a gap.
        outward = (-u, u) if not truth.is_gap else (u, -u)
        out = []
        for p, away in zip((a, b), outward):
            q = p + rng.normal(0.0, self.jitter_px, 2)
            if rng.random() < self.off_object_prob:
                q = q + away * rng.uniform(1.0, self.off_object_px)
            x = float(np.clip(math.floor(q[0] + 0.5), 0, width - 1))
            y = float(np.clip(math.floor(q[1] + 0.5), 0, height - 1))
            out.append((x, y))
        if out[0] == out[1]:  # a segment needs two different pixels
            out[1] = (float(np.clip(out[1][0] + 1, 0, width - 1)), out[1][1])
        return out[0], out[1]
