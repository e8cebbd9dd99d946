"""A small synthetic poster rig for the measurement-core tests (its own ray casting, not sim/'s renderer).

A tilted rectangular poster in front of a fronto-parallel wall, seen by a pinhole camera with
registered disparity: Gaussian disparity noise, quantization, foreground fattening at the
poster's border, a band of "contention" outliers (the other stereo pair's wrong match) around
the border, random holes. Ground truth: the poster's edge-to-edge segment in 3D.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factories import camera
from measure import Frame, PinholeCamera

W, H = 960, 540
FX = 750.0
BASELINE = 0.1


@dataclass(frozen=True)
class Case:
    frame: Frame
    p1_m: np.ndarray
    p2_m: np.ndarray
    click1: tuple[float, float]
    click2: tuple[float, float]
    true_px1: tuple[float, float]
    true_px2: tuple[float, float]

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.p2_m - self.p1_m))


def rotation(yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return ry @ rx @ rz


def project(cam: PinholeCamera, p: np.ndarray) -> tuple[float, float]:
    return (float(cam.fx * p[0] / p[2] + cam.cx), float(cam.fy * p[1] / p[2] + cam.cy))


def poster_depth(cam: PinholeCamera, center: np.ndarray, rot: np.ndarray, half: tuple[float, float], wall_z: float | None):
    """Per-pixel true depth (m) and a poster mask (NaN depth where nothing is hit)."""
    xs = (np.arange(cam.width) - cam.cx) / cam.fx
    ys = (np.arange(cam.height) - cam.cy) / cam.fy
    rx, ry = xs[None, :], ys[:, None]  # broadcast, not a grid: the same numbers per pixel
    n = rot[:, 2]
    # The arithmetic of t = (n.c) / (n.ray), p = t ray - c and its in-plane coordinates (lu, lw), in the
    # same order, written into a few image-sized arrays instead of a new one per operation.
    t = n[0] * rx + n[1] * ry
    t += n[2]
    np.divide(n @ center, t, out=t)
    px, py, pz = t * rx, t * ry, t - center[2]
    px -= center[0]
    py -= center[1]
    lu, tmp = px * rot[0, 0], np.multiply(py, rot[1, 0])
    lu += tmp
    lu += np.multiply(pz, rot[2, 0], out=tmp)
    lw = np.multiply(px, rot[0, 1], out=px)
    lw += np.multiply(py, rot[1, 1], out=tmp)
    lw += np.multiply(pz, rot[2, 1], out=tmp)
    poster = np.abs(lu, out=lu) <= half[0]
    poster &= np.abs(lw, out=lw) <= half[1]
    poster &= t > 0
    depth = t
    depth[~poster] = np.nan if wall_z is None else wall_z
    return depth, poster


def degrade(
    depth: np.ndarray,
    poster: np.ndarray,
    rng: np.random.Generator,
    *,
    fb: float,
    noise_px: float = 0.15,
    quantization: float | None = 0.25,
    contention: float = 0.5,
    band_px: int = 15,
    fatten_px: int = 3,
    holes: float = 0.03,
) -> np.ndarray:
    """Disparity (float32 px, NaN = none) of a true depth map, with the sensor's faults."""
    import cv2

    d = fb / depth
    k = np.ones((2 * band_px + 3, 2 * band_px + 3), np.uint8)
    fg_disp = cv2.dilate(np.where(poster, d, 0).astype(np.float32), k)
    bg = np.where(poster, 0, fb / np.where(poster, 1.0, depth)).astype(np.float32)
    background = cv2.dilate(bg, k)
    if fatten_px > 0:
        k = np.ones((2 * fatten_px + 1, 2 * fatten_px + 1), np.uint8)
        grown = cv2.dilate(poster.astype(np.uint8), k).astype(bool)
        fg = cv2.dilate(np.where(poster, d, 0).astype(np.float32), k)
        d = np.where(grown & ~poster, fg, d)
    d = d + rng.normal(0.0, noise_px, d.shape)
    if contention > 0 and band_px > 0:
        k = np.ones((2 * band_px + 1, 2 * band_px + 1), np.uint8)
        band = cv2.dilate(poster.astype(np.uint8), k).astype(bool) & ~cv2.erode(poster.astype(np.uint8), k).astype(bool)
        wrong = np.flatnonzero(band & (rng.random(d.shape) < contention))
        # Every draw is made over the whole image (the same stream whatever the band), the arithmetic only
        # where a pixel is replaced: a few percent of the image.
        noise, scale = rng.normal(0.0, noise_px, d.shape).ravel()[wrong], rng.uniform(0.6, 1.4, d.shape).ravel()[wrong]
        take_swap = (rng.random(d.shape) < 0.5).ravel()[wrong]
        # The other pair's wrong match near a depth edge is the surface on the other side
        # of the edge (poster <-> wall), as in mixed windows; the rest are gross errors.
        behind = fb / (fb / np.maximum(background.ravel()[wrong], 1e-6) + 1e-9)
        swap = np.where(poster.ravel()[wrong], behind, fg_disp.ravel()[wrong]) + noise
        d = d.ravel()
        d[wrong] = np.where(take_swap, swap, d[wrong] * scale)
        d = d.reshape(depth.shape)
    if quantization:
        d = np.round(d / quantization) * quantization
    d[rng.random(d.shape) < holes] = np.nan
    return d.astype(np.float32)


def poster_case(
    distance_m: float,
    rng: np.random.Generator,
    *,
    target: str = "width",
    yaw_deg: float = 0.0,
    pitch_deg: float = 0.0,
    half: tuple[float, float] = (0.5, 0.35),
    wall_gap_m: float = 2.0,
    jitter_px: float = 3.0,
    **degrade_kw,
) -> Case:
    """A poster at ``distance_m`` (its centre), measured across its width or height edge to edge."""
    cam = camera(W, H, FX)
    center = np.array([rng.uniform(-0.1, 0.1) * distance_m, rng.uniform(-0.05, 0.05) * distance_m, distance_m])
    rot = rotation(yaw_deg, pitch_deg)
    depth, poster = poster_depth(cam, center, rot, half, distance_m + wall_gap_m)
    disp = degrade(depth, poster, rng, fb=cam.fx * BASELINE, **degrade_kw)
    s = rng.uniform(-0.6, 0.6)
    if target == "width":
        a, b = np.array([-half[0], s * half[1], 0]), np.array([half[0], s * half[1], 0])
    else:
        a, b = np.array([s * half[0], -half[1], 0]), np.array([s * half[0], half[1], 0])
    p1, p2 = center + rot @ a, center + rot @ b
    t1, t2 = project(cam, p1), project(cam, p2)
    j = rng.normal(0.0, jitter_px, 4)
    c1 = (min(max(t1[0] + j[0], 0), W - 1), min(max(t1[1] + j[1], 0), H - 1))
    c2 = (min(max(t2[0] + j[2], 0), W - 1), min(max(t2[1] + j[3], 0), H - 1))
    frame = Frame(image=np.zeros((H, W, 3), np.uint8), disparity=disp, camera=cam, baseline_m=BASELINE)
    return Case(frame, p1, p2, c1, c2, t1, t2)
