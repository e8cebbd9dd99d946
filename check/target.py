"""The board as a depth target in one frame: its pose from the image alone, and the disparity on it.

Steps of :func:`board_view`: the board's pose from the detected corners (``solvePnP`` on the
frame's pinhole camera, no disparity used) gives the distance (m) and tilt (degrees); inside the
hull of the corners, the share of pixels with valid disparity (fill rate), the RMS distance (m) of
their 3D points to a least-squares plane (plane-fit RMS, the figure of the RealSense Depth Quality
Tool), a robust plane in disparity space (noise in px and as depth, share of outliers); and the
median stereo depth at the corners over the pose's depth (1 when the baseline is right).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from device.calibration.board import BoardSpec, Detection
from measure import Frame

from check.errors import CheckError
from check.pairs import board_points, corner_grid


@dataclass(frozen=True)
class BoardView:
    """The board as a depth target in one frame: pose from the image, disparity on the board."""

    frame: int
    n_corners: int
    distance_m: float  # Z of the board centre from the corners' pose (solvePnP), camera frame
    tilt_deg: float  # angle between the board's normal and the optical axis
    px_per_square: float
    fill_rate: float  # share of pixels in the corners' hull with valid disparity
    plane_rms_m: float  # RMS of the board's 3D points about their least-squares plane (Depth Quality Tool)
    plane_noise_m: float  # robust sigma about a robust plane, as depth at the board's centre
    plane_noise_px: float  # the same in disparity
    outlier_share: float  # share of the board's points > 3 sigma off that plane
    depth_ratio: float  # median stereo depth / pose depth at the detected corners
    disparity_px: float  # median disparity on the board (d + doffs)


def board_pose(board: BoardSpec, det: Detection, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3x3) and translation (3, m) of the board in the camera frame from the corners alone."""
    cam = frame.camera
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], np.float64)
    obj = board_points(board, det.ids)
    img = det.corners.astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CheckError("the board's pose could not be solved from its corners; hold it flat and in full view")
    # IPPE's closed form alone leaves the tilt visibly off; refined to the reprojection-error minimum
    # (docs/decisions/check-verdict.md, "Board pose").
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    return R, tvec.reshape(3)


def _hull_mask(det: Detection, shape: tuple[int, int]) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    hull = cv2.convexHull(det.corners.astype(np.float32)).astype(np.int32)
    cv2.fillConvexPoly(mask, hull, 1)
    return mask.astype(bool)


def _points(frame: Frame, mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask & np.isfinite(frame.disparity))
    d = frame.disparity[ys, xs].astype(np.float64) + frame.doffs
    keep = d > 0
    ys, xs, d = ys[keep], xs[keep], d[keep]
    cam = frame.camera
    z = cam.fx * frame.baseline_m / d
    return np.stack([(xs - cam.cx) * z / cam.fx, (ys - cam.cy) * z / cam.fy, z], axis=1)


def plane_fit_rms(points: np.ndarray) -> float:
    """RMS distance (m) of 3D points (N x 3) to their least-squares plane (smallest singular vector)."""
    if len(points) < 3:
        return math.nan
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return float(s[-1] / math.sqrt(len(points)))


def robust_plane(xs: np.ndarray, ys: np.ndarray, d: np.ndarray, iterations: int = 10) -> tuple[float, float, float]:
    """A plane fitted in disparity space, ``d = a x + b y + c`` (a 3D plane is one there, and the pixel
    coordinates have no outliers to lever the fit), bisquare-reweighted from the median: the noise
    (px, 1.4826 MAD of the residuals), the share of pixels further than 3 of those from it (wrong matches,
    which the least-squares RMS mixes in), and the fitted disparity at the pixels' centroid (px)."""
    if len(d) < 3:
        return math.nan, math.nan, math.nan
    A = np.stack([xs - xs.mean(), ys - ys.mean(), np.ones(len(d))], axis=1)
    coef = np.array([0.0, 0.0, float(np.median(d))])
    for _ in range(iterations):
        r = d - A @ coef
        scale = max(1.4826 * float(np.median(np.abs(r))), 1e-6)
        sw = np.sqrt(np.clip(1 - (r / (4.685 * scale)) ** 2, 0, None) ** 2 + 1e-12)
        coef, *_ = np.linalg.lstsq(A * sw[:, None], d * sw, rcond=None)
    r = d - A @ coef
    sigma = 1.4826 * float(np.median(np.abs(r)))
    return sigma, float(np.mean(np.abs(r) > 3 * sigma)), float(coef[2])


def board_view(board: BoardSpec, det: Detection, frame: Frame, index: int) -> BoardView:
    """Pose, fill rate, plane-fit RMS and stereo-vs-pose depth of the board in one frame."""
    R, t = board_pose(board, det, frame)
    centre = R @ np.array([board.squares_x * board.square_m / 2, board.squares_y * board.square_m / 2, 0.0]) + t
    tilt = math.degrees(math.acos(min(1.0, abs(float(R[2, 2])))))
    mask = _hull_mask(det, frame.disparity.shape)
    valid = np.isfinite(frame.disparity[mask])
    pts = _points(frame, mask)
    ys, xs = np.nonzero(mask & np.isfinite(frame.disparity))
    sigma_px, outliers, d_centre = robust_plane(xs.astype(np.float64), ys.astype(np.float64),
                                                frame.disparity[ys, xs].astype(np.float64))
    # dZ = Z / (d + doffs) * dd: the disparity noise as depth at the board's distance
    noise = float(frame.camera.fx * frame.baseline_m / (d_centre + frame.doffs) ** 2 * sigma_px)
    pose_z = (board_points(board, det.ids) @ R.T + t)[:, 2]
    d = _window_median(frame.disparity, det.corners, 2) + frame.doffs
    with np.errstate(invalid="ignore", divide="ignore"):
        stereo_z = frame.camera.fx * frame.baseline_m / d
    ratio = stereo_z / pose_z
    ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
    grid = corner_grid(board, det.ids)
    neighbours = np.abs(grid[:, None, :] - grid[None, :, :]).sum(axis=2) == 1
    steps = np.linalg.norm(det.corners[:, None, :] - det.corners[None, :, :], axis=2)[neighbours]
    return BoardView(
        frame=index,
        n_corners=len(det.ids),
        distance_m=float(centre[2]),
        tilt_deg=tilt,
        px_per_square=float(np.median(steps)) if steps.size else math.nan,
        fill_rate=float(valid.mean()) if valid.size else 0.0,
        plane_rms_m=plane_fit_rms(pts),
        plane_noise_m=noise,
        plane_noise_px=sigma_px,
        outlier_share=outliers,
        depth_ratio=float(np.median(ratio)) if ratio.size else math.nan,
        disparity_px=float(np.nanmedian(frame.disparity[mask])) + frame.doffs if valid.any() else math.nan,
    )


def _window_median(disparity: np.ndarray, pts: np.ndarray, r: int) -> np.ndarray:
    """Median disparity in a (2r+1)^2 window around each point (NaN-aware), vectorised over points."""
    h, w = disparity.shape
    cx = np.clip(np.rint(pts[:, 0]).astype(int), r, w - 1 - r)
    cy = np.clip(np.rint(pts[:, 1]).astype(int), r, h - 1 - r)
    off = np.arange(-r, r + 1)
    win = disparity[cy[:, None, None] + off[None, :, None], cx[:, None, None] + off[None, None, :]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a window without data gives NaN, said once here
        return np.nanmedian(win.reshape(len(pts), -1), axis=1)
