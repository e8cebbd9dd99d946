"""Procedural materials of the simulated scenes and the lighting presets that shade them.

Textures are looked up by each primitive's texture coordinates in metres, so their scale on screen
follows the distance like a real surface's would. Low-amplitude materials (wall paint) are what a
passive stereo camera cannot match; they become holes and contended regions in the sensor model.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

# Colours are BGR in [0, 1] (OpenCV order, like the frames).


@dataclass(frozen=True)
class Material:
    """Base colour (BGR, 0..1), grain amplitude (0..1), grain period (m) and a pattern name."""

    base: tuple[float, float, float]
    amplitude: float
    grain_m: float
    pattern: str = "noise"


MATERIALS: dict[str, Material] = {
    "paint": Material((0.78, 0.84, 0.86), 0.015, 0.004),
    "wallpaper": Material((0.55, 0.70, 0.78), 0.25, 0.01, "check"),
    "wood": Material((0.28, 0.45, 0.62), 0.22, 0.006, "planks"),
    "poster": Material((0.9, 0.9, 0.9), 1.0, 0.001, "poster"),
    "cardboard": Material((0.36, 0.52, 0.66), 0.12, 0.003, "tape"),
    "shirt": Material((0.60, 0.35, 0.20), 0.30, 0.02, "check"),
    "jeans": Material((0.45, 0.28, 0.18), 0.15, 0.003),
    "shoe": Material((0.12, 0.12, 0.14), 0.10, 0.003),
    "skin": Material((0.55, 0.66, 0.85), 0.06, 0.004),
    # A printed ChArUco board (sim/charuco.py gives its colours): ink at 0.06, paper at 0.90.
    "charuco": Material((0.48, 0.48, 0.48), 1.0, 0.001, "charuco"),
}


@dataclass(frozen=True)
class Lighting:
    """How a lighting condition changes the image and the sensor (the paper's indoor / mixed / outdoor).

    noise_px: Gaussian disparity noise (reference pixels); hole_fraction: share of low-texture pixels
    without disparity; contrast: texture amplitude factor; ambient/diffuse/exposure/tint: shading.
    """

    noise_px: float
    hole_fraction: float
    contrast: float
    ambient: float
    diffuse: float
    exposure: float
    tint: tuple[float, float, float]
    light_dir: tuple[float, float, float]
    image_noise: float


LIGHTING: dict[str, Lighting] = {
    # Indoor: dim, even light; more sensor noise, full texture contrast.
    "indoor": Lighting(0.20, 0.30, 1.00, 0.55, 0.45, 0.95, (0.85, 0.95, 1.05), (0.3, 0.8, 0.5), 3.0),
    # Mixed: window plus lamps; uneven light and shadows, somewhat lower contrast.
    "mixed": Lighting(0.28, 0.40, 0.80, 0.40, 0.70, 1.00, (0.95, 1.0, 1.0), (-0.5, 0.6, 0.6), 2.5),
    # Outdoor: bright and hard; bleached, low-contrast texture, the most holes and the most noise at range.
    "outdoor": Lighting(0.35, 0.50, 0.60, 0.35, 0.95, 1.20, (1.05, 1.0, 0.95), (0.6, 0.7, 0.4), 2.0),
}


@lru_cache(maxsize=32)
def noise_tile(seed: int, size: int = 1024) -> np.ndarray:
    """Tileable value noise in [-1, 1] (size x size): a sum of octaves of bilinearly upsampled random grids."""
    import cv2

    rng = np.random.default_rng(seed)
    out = np.zeros((size, size), np.float32)
    weight = 0.0
    for cells, w in ((size // 2, 1.0), (size // 8, 0.6), (size // 32, 0.4)):
        grid = rng.uniform(-1, 1, (cells, cells)).astype(np.float32)
        grid = np.pad(grid, ((0, 1), (0, 1)), mode="wrap")  # wrap so the tile repeats seamlessly
        step = size / cells
        up = cv2.resize(grid, (int(round((cells + 1) * step)), int(round((cells + 1) * step))), interpolation=cv2.INTER_LINEAR)
        out += w * up[:size, :size]
        weight += w
    out /= weight
    out /= max(float(np.abs(out).max()), 1e-6)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=4)
def poster_image(seed: int, width_mm: int, height_mm: int) -> np.ndarray:
    """A poster (BGR float32 0..1, 1 px per mm): title, coloured shapes, text lines, a photo-like block."""
    import cv2

    rng = np.random.default_rng(seed)
    w, h = width_mm, height_mm
    canvas = np.empty((h, w, 3), np.uint8)  # OpenCV draws text on 8-bit images only
    canvas[:] = rng.integers(190, 248, 3).astype(np.uint8)
    cv2.rectangle(canvas, (0, 0), (w - 1, h - 1), (40, 40, 40), thickness=max(6, w // 60))
    scale, thick = w / 220, max(2, w // 80)
    cv2.putText(canvas, "DEPTH", (w // 12, h // 8), cv2.FONT_HERSHEY_DUPLEX, scale, (25, 25, 130), thick)
    cv2.putText(canvas, "RULER", (w // 12, h // 8 + h // 10), cv2.FONT_HERSHEY_DUPLEX, scale, (130, 40, 25), thick)
    for _ in range(14):
        colour = tuple(int(c) for c in rng.integers(15, 240, 3))
        cx, cy = int(rng.uniform(0.1, 0.9) * w), int(rng.uniform(0.3, 0.65) * h)
        if rng.random() < 0.5:
            cv2.circle(canvas, (cx, cy), int(rng.uniform(0.03, 0.12) * w), colour, -1)
        else:
            sx, sy = int(rng.uniform(0.04, 0.2) * w), int(rng.uniform(0.03, 0.12) * h)
            cv2.rectangle(canvas, (cx - sx, cy - sy), (cx + sx, cy + sy), colour, -1)
    y = int(0.70 * h)
    while y < 0.95 * h:
        x0, length = int(0.08 * w), int(rng.uniform(0.4, 0.84) * w)
        cv2.rectangle(canvas, (x0, y), (x0 + length, y + max(4, h // 110)), (50, 50, 50), -1)
        y += max(10, h // 45)
    img = canvas.astype(np.float32) / 255.0
    grain = noise_tile(seed + 1, 512)
    img += 0.06 * np.tile(grain, (h // 512 + 1, w // 512 + 1))[:h, :w, None]
    np.clip(img, 0, 1, out=img)
    img.setflags(write=False)
    return img


def pattern(material: str, uv: np.ndarray, *, seed: int, poster_mm: tuple[int, int] = (594, 841)) -> np.ndarray:
    """The lighting-independent part of a material at texture coordinates ``uv`` (N x 2, metres): the
    poster's colours (N x 3 BGR, 0..1), or for other materials a grain value per point (N,), ~[-1, 1]."""
    mat = MATERIALS[material]
    if mat.pattern == "poster":
        img = poster_image(seed, *poster_mm)
        h, w = img.shape[:2]
        # uv = (s, r) from the poster centre; r grows downwards on the poster (its v axis points down).
        col = np.clip(((uv[:, 0] * 1000.0) + w / 2).astype(np.int64), 0, w - 1)
        row = np.clip(((uv[:, 1] * 1000.0) + h / 2).astype(np.int64), 0, h - 1)
        return img[row, col]
    tile = noise_tile(seed + sum(map(ord, material)))  # a different grain per material, stable across runs
    size = tile.shape[0]
    i = np.floor(uv[:, 1] / mat.grain_m).astype(np.int64) % size
    j = np.floor(uv[:, 0] / mat.grain_m).astype(np.int64) % size
    n = tile[i, j]
    if mat.pattern == "planks":
        plank = np.floor(uv[:, 0] / 0.14)
        n = 0.6 * n + 0.4 * np.sin(plank * 2.3) + 0.3 * (np.abs((uv[:, 0] / 0.14) % 1.0 - 0.5) > 0.48)
    elif mat.pattern == "check":
        check = (np.floor(uv[:, 0] / 0.04) + np.floor(uv[:, 1] / 0.04)) % 2
        n = 0.4 * n + (check - 0.5) * 1.2
    elif mat.pattern == "tape":
        n = n - 1.5 * (np.abs(uv[:, 0]) < 0.03)
    return n.astype(np.float32)


def albedo(material: str, pat: np.ndarray, contrast: float) -> np.ndarray:
    """Reflectance (N x 3 BGR, 0..1) of ``material`` from its ``pattern`` under a lighting's ``contrast``."""
    mat = MATERIALS[material]
    base = np.asarray(mat.base, np.float32)
    if pat.ndim == 2:
        mean = np.float32(base.mean())
        return np.clip(mean + np.float32(contrast) * (pat - mean), 0, 1)
    shade = 1.0 + np.float32(contrast * mat.amplitude) * pat
    return np.clip(base[None, :] * shade[:, None], 0, 1)
