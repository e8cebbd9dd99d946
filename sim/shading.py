"""Colour renders of a ray-cast view: Lambert shading of its textured surfaces under a lighting preset,
each preset shaded the first time it is asked for (sim.scenes.View.renders)."""

from __future__ import annotations

import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from sim.textures import LIGHTING, albedo


@dataclass(frozen=True)
class Painted:
    """What shading one visible surface needs under any lighting: its material, pixels (flat indices),
    normals (N x 3, or one 3-vector for a plane) and the lighting-independent pattern (sim.textures)."""

    material: str
    index: np.ndarray
    normals: np.ndarray
    pattern: np.ndarray


class Renders(Mapping[str, np.ndarray]):
    """A view's colour render per lighting preset (H x W x 3 uint8 BGR, read-only), shaded the first time
    it is asked for: a view is mostly seen under one lighting. Thread-safe; once every preset is shaded
    the surfaces' shading inputs are let go."""

    def __init__(self, painted: tuple[Painted, ...], shape: tuple[int, int]) -> None:
        self._painted: tuple[Painted, ...] | None = painted
        self._shape = shape
        self._done: dict[str, np.ndarray] = {}
        self._lock = threading.Lock()

    def __getitem__(self, lighting: str) -> np.ndarray:
        with self._lock:
            img = self._done.get(lighting)
            if img is None:
                if lighting not in LIGHTING or self._painted is None:
                    raise KeyError(lighting)
                img = shade(self._painted, self._shape, lighting)
                img.setflags(write=False)
                self._done[lighting] = img
                if len(self._done) == len(LIGHTING):
                    self._painted = None
            return img

    def __iter__(self) -> Iterator[str]:
        return iter(LIGHTING)

    def __len__(self) -> int:
        return len(LIGHTING)


def shade(painted: tuple[Painted, ...], shape: tuple[int, int], lighting: str) -> np.ndarray:
    """Lambert shading of the visible textured surfaces."""
    light = LIGHTING[lighting]
    h, w = shape
    img = np.empty((h * w, 3), np.float32)
    img[:] = np.array([0.95, 0.85, 0.75], np.float32)  # what lies beyond every surface: a pale sky
    to_light = -np.asarray(light.light_dir, np.float64)
    to_light /= np.linalg.norm(to_light)
    gain = light.exposure * np.asarray(light.tint, np.float32)
    for surf in painted:
        alb = albedo(surf.material, surf.pattern, light.contrast)
        lambert = np.maximum(surf.normals @ to_light, 0.0).astype(np.float32)  # one value for a plane
        img[surf.index] = alb * (light.ambient + light.diffuse * lambert)[..., None] * gain
    np.clip(img, 0, 1, out=img)
    img *= np.float32(255.0)
    img += np.float32(0.5)
    return img.astype(np.uint8).reshape(h, w, 3)
