"""The printed ChArUco board of the "charuco" scene: its texture, and where its corners truly are.

The board is OpenCV's own ``CharucoBoard.generateImage`` (the same board ``depthruler calibrate
--board-png`` prints), laid on the scene's standing board with half a square of white margin, so a
chessboard corner with id k lies exactly at ``sim.scenes.charuco_corner_offsets(board)[k]`` on the sheet.

A texture looked up once per pixel centre puts every black/white edge on the pixel grid (aliasing),
which moves detected corners by up to a few tenths of a pixel. The board is therefore supersampled:
``SUPERSAMPLE`` x ``SUPERSAMPLE`` rays per pixel are intersected with the board's plane, the texture is
read bilinearly at each and averaged, as a sensor integrates light over a pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from measure import PinholeCamera

from sim.raycast import Pose, Rect, Surface
from sim.scenes import SceneParams, board_frame, charuco_corner_offsets, charuco_sheet_m, get_view

SUPERSAMPLE = 4
TEXELS_PER_SQUARE = 96


@lru_cache(maxsize=4)
def board_texture(board: tuple[int, int, float, float, str]) -> tuple[np.ndarray, float]:
    """The sheet as a float32 grey image in [0, 1] and its texels per metre."""
    from device.calibration.board import BoardSpec

    sx, sy, square, marker, dictionary = board
    spec = BoardSpec(sx, sy, square, marker, dictionary)
    per_m = TEXELS_PER_SQUARE / square
    w, h, margin = charuco_sheet_m(board)
    img = spec.board().generateImage((int(round(w * per_m)), int(round(h * per_m))),
                                     marginSize=int(round(margin * per_m)), borderBits=1)
    tex = img.astype(np.float32) / 255.0
    tex.setflags(write=False)
    return tex, per_m


def _bilinear(tex: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    h, w = tex.shape
    col = np.clip(col, 0.0, w - 1.001)
    row = np.clip(row, 0.0, h - 1.001)
    c0, r0 = col.astype(np.int64), row.astype(np.int64)
    fc, fr = (col - c0).astype(np.float32), (row - r0).astype(np.float32)
    top = tex[r0, c0] * (1 - fc) + tex[r0, c0 + 1] * fc
    bottom = tex[r0 + 1, c0] * (1 - fc) + tex[r0 + 1, c0 + 1] * fc
    return top * (1 - fr) + bottom * fr


def board_pattern(surface: Surface, camera: PinholeCamera, pose: Pose, board: tuple) -> np.ndarray:
    """Colours (N x 3 BGR, 0..1) of the board's visible pixels, supersampled (see the module docstring)."""
    tex, per_m = board_texture(tuple(board))
    w_m, h_m, _ = charuco_sheet_m(board)
    prim = surface.prim
    assert isinstance(prim, Rect), "the ChArUco board is a flat Rect"
    c, u, v = (np.asarray(a, np.float64) for a in (prim.centre, prim.u, prim.v))
    n = np.cross(u, v)
    o = pose.C
    ys, xs = np.divmod(surface.index, camera.width)
    acc = np.zeros(surface.index.size, np.float32)
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    R = pose.R
    for oy in offsets:
        for ox in offsets:
            ray = np.stack([(xs + ox - camera.cx) / camera.fx, (ys + oy - camera.cy) / camera.fy,
                            np.ones(xs.size)], axis=1) @ R.T
            t = -((o - c) @ n) / (ray @ n)
            q = o + t[:, None] * ray - c
            # Sheet texel of board point (s, r) from the sheet centre: OpenCV's pixel-centre convention.
            acc += _bilinear(tex, (q @ u + w_m / 2) * per_m - 0.5, (q @ v + h_m / 2) * per_m - 0.5)
    grey = np.float32(0.06) + np.float32(0.84 / (SUPERSAMPLE * SUPERSAMPLE)) * acc  # ink 0.06, paper 0.90
    return np.repeat(grey[:, None], 3, axis=1)


@dataclass(frozen=True)
class BoardTruth:
    """Where the board's chessboard corners are in a simulated view: ids (K,), camera-frame points
    (K x 3, m, x right, y down, z forward) and their exact (sub-pixel) image positions (K x 2, px)."""

    ids: np.ndarray
    points_m: np.ndarray
    pixels: np.ndarray


def board_truth(params: SceneParams) -> BoardTruth:
    """The true corner positions of the "charuco" scene ``params`` (distance, pose and board)."""
    if params.scene != "charuco":
        raise ValueError(f"scene {params.scene!r} shows no ChArUco board; use scene 'charuco'")
    view = get_view(params)
    c, u, v = board_frame(params)
    k = charuco_corner_offsets(params.charuco)
    world = c[None, :] + k[:, :1] * u[None, :] + k[:, 1:] * v[None, :]
    # The board's centre lies at the placer's (0, camera height, distance); board_frame gives the same
    # axes as the scene's Rect, so these are the printed corners exactly.
    return BoardTruth(np.arange(len(k)), view.pose.to_camera(world), view.pose.project(view.camera, world))
