"""`depthruler check`: how accurate are lengths from this camera, here, today, against a printed ChArUco board.

The board carries dozens of exactly known lengths: chessboard corner k sits at ``(i, j) * square`` on the
sheet (i = k mod (squares_x - 1), j = k div (squares_x - 1)). Per frame:

1. **Find the board** in the colour image with OpenCV's ``CharucoDetector`` (sub-pixel corners).
2. **Pairs of known length**: every pair of detected corners on one row, one column or one 45 degree
   diagonal, and the two full-board diagonals; from one square to the board's size.
3. **Measure** each pair with the default method (``MeasureOptions()``) with the two corners as the
   clicks, as a careful person would click them, and score it with Eq. 8 (``measure.metrics.accuracy``), the
   signed error in % of the true length, the verdict ("good") and whether the true length lies inside
   the reported 95 % interval.
4. **The board as a depth target**: its pose from the corners alone (``solvePnP`` on the frame's pinhole
   camera; no disparity used) gives distance and tilt; inside the hull of the detected corners, the
   share of pixels with valid disparity (fill rate) and the RMS distance of their 3D points to a
   least-squares plane (plane-fit RMS, the figure of the RealSense Depth Quality Tool); stereo depth at
   the corners against the pose's depth.

Over several frames the figures pool all pairs, and the frame-to-frame spread is the median, over
pairs seen in two frames or more, of each pair's standard deviation of the measured length.

Why the figures separate causes (the verdict, :func:`findings`): with ``Z = fx B / d`` and
``X = (x - cx) B / d``, a baseline off by a factor k scales every depth and every length by k, so lengths
read k - 1 long at every distance and length *and* stereo depth disagrees with the board's pose by the
same factor (the pose does not use the baseline). A board printed at another scale than ``--square-mm``
says gives the same signature (the true lengths and the pose's depth are both off), which is why the
advice is to measure a printed square first. A disparity offset instead gives an error growing with
distance; bad end points give an error of fixed millimetres, large in % on short pairs only: the fit
``error = k * length + c`` over all pairs tells a scale (k) from an end-point offset (c).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from device.calibration.stereo import BoardSpec, Detection, detect_board
from measure import Frame, MeasureError, MeasureOptions, measure_distance


from measure.metrics import accuracy, signed_error_pct

MIN_CORNERS = 6
LONG_SQUARES = 2.5  # "long" pairs: 3 squares or more
LENGTH_BINS = ((1.0, 1.5, "1 square"), (1.5, 2.5, "2 squares"), (2.5, 4.5, "3-4 squares"), (4.5, math.inf, "5+ squares"))


class CheckError(ValueError):
    """The check cannot run as asked (no board in view, too few corners); the message says what to change."""


@dataclass(frozen=True)
class CornerPair:
    """Two chessboard corners (ids) of known distance ``length_m``: kind "row" | "column" | "diagonal"."""

    id1: int
    id2: int
    length_m: float
    kind: str
    squares: float  # the length in squares


@dataclass(frozen=True)
class PairResult:
    """One pair measured on one frame (metres, pixels of the colour image)."""

    frame: int
    pair: CornerPair
    p1_px: tuple[float, float]
    p2_px: tuple[float, float]
    measured_m: float
    interval_m: tuple[float, float]
    quality: str
    accuracy: float
    error_pct: float
    covered: bool


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


@dataclass(frozen=True)
class CheckResult:
    """Everything one check measured: per pair, per frame, and the frames that showed no board."""

    board: BoardSpec
    pairs: tuple[PairResult, ...]
    views: tuple[BoardView, ...]
    missed_frames: tuple[int, ...] = ()
    detections: tuple[Detection, ...] = field(default=(), repr=False)  # per view, for drawing
    fx_baseline: float = math.nan  # fx * B (px m) of the first frame with the board


def corner_grid(board: BoardSpec, ids: np.ndarray) -> np.ndarray:
    """(i, j) grid position (N x 2, squares) of chessboard corner ids."""
    ids = np.asarray(ids, np.int64)
    return np.stack([ids % (board.squares_x - 1), ids // (board.squares_x - 1)], axis=1)


def board_points(board: BoardSpec, ids: np.ndarray) -> np.ndarray:
    """Board-frame 3D points (N x 3, m) of chessboard corner ids, as OpenCV's CharucoBoard places them."""
    return np.asarray(board.board().getChessboardCorners(), np.float64)[np.asarray(ids, np.int64)]


def board_pairs(board: BoardSpec, ids: Sequence[int]) -> list[CornerPair]:
    """All pairs of the detected ``ids`` on one row, column or 45 degree diagonal, plus the full diagonals."""
    ids = sorted(int(i) for i in ids)
    grid = {i: tuple(int(v) for v in g) for i, g in zip(ids, corner_grid(board, np.array(ids)))}
    nx, ny = board.squares_x - 1, board.squares_y - 1
    corners_of_board = {(0, 0), (nx - 1, ny - 1), (nx - 1, 0), (0, ny - 1)}
    out = []
    for a_i, a in enumerate(ids):
        for b in ids[a_i + 1:]:
            (xa, ya), (xb, yb) = grid[a], grid[b]
            dx, dy = abs(xb - xa), abs(yb - ya)
            if dy == 0:
                kind = "row"
            elif dx == 0:
                kind = "column"
            elif dx == dy or ({grid[a], grid[b]} <= corners_of_board and dx == nx - 1 and dy == ny - 1):
                kind = "diagonal"
            else:
                continue
            squares = math.hypot(dx, dy)
            out.append(CornerPair(a, b, squares * board.square_m, kind, squares))
    return out


def board_pose(board: BoardSpec, det: Detection, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3x3) and translation (3, m) of the board in the camera frame from the corners alone."""
    cam = frame.camera
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], np.float64)
    obj = board_points(board, det.ids)
    img = det.corners.astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CheckError("the board's pose could not be solved from its corners; hold it flat and in full view")
    # IPPE's closed form is 0.5 deg off on a square-on board with corners good to 0.1 px; the
    # reprojection-error minimum from there is within 0.01 deg (simulated board at 1-4 m).
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


def robust_line(x: np.ndarray, y: np.ndarray, iterations: int = 10) -> tuple[float, float]:
    """Slope and intercept of y = k x + c, bisquare-reweighted (a few wild pairs do not set them)."""
    A = np.stack([x, np.ones_like(x)], axis=1)
    k, c = float(np.median(y / x)), 0.0  # start from a pure scale, which a few wild pairs do not move
    for _ in range(iterations):
        r = y - (k * x + c)
        scale = max(1.4826 * float(np.median(np.abs(r))), 1e-12)
        sw = np.clip(1 - (r / (4.685 * scale)) ** 2, 0, None) + 1e-6  # sqrt of the bisquare weight
        (k, c), *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    return float(k), float(c)


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


def measure_pairs(frame: Frame, det: Detection, pairs: Iterable[CornerPair], index: int = 0,
                  options: MeasureOptions = MeasureOptions()) -> list[PairResult]:
    """Each pair measured as if clicked at its two detected corners; see the module docstring."""
    where = {int(i): (float(c[0]), float(c[1])) for i, c in zip(det.ids, det.corners)}
    out = []
    for pair in pairs:
        p1, p2 = where[pair.id1], where[pair.id2]
        try:
            m = measure_distance(frame, p1, p2, options)
        except MeasureError:
            continue  # no depth near this line: counted by the fill rate, not as an error of the method
        if not math.isfinite(m.distance_m):
            continue
        lo, hi = m.interval_m
        out.append(PairResult(
            frame=index, pair=pair, p1_px=p1, p2_px=p2, measured_m=float(m.distance_m),
            interval_m=(float(lo), float(hi)), quality=m.quality,
            accuracy=float(accuracy(pair.length_m, m.distance_m)),
            error_pct=float(signed_error_pct(np.array(pair.length_m), np.array(m.distance_m))),
            covered=bool(lo <= pair.length_m <= hi),
        ))
    return out


def run_check(frames: Iterable[Frame], board: BoardSpec, options: MeasureOptions = MeasureOptions()) -> CheckResult:
    """The check on ``frames`` (each with its colour image and registered disparity) of ``board``.

    Raises :class:`CheckError` when no frame shows at least ``MIN_CORNERS`` corners of the board.
    """
    detector = cv2.aruco.CharucoDetector(board.board())
    pairs: list[PairResult] = []
    views: list[BoardView] = []
    dets: list[Detection] = []
    missed: list[int] = []
    fx_b = math.nan
    for index, frame in enumerate(frames):
        det = detect_board(detector, frame.image)
        if det is None or len(det.ids) < MIN_CORNERS:
            missed.append(index)
            continue
        views.append(board_view(board, det, frame, index))
        dets.append(det)
        if not views[1:]:
            fx_b = frame.camera.fx * frame.baseline_m
        pairs.extend(measure_pairs(frame, det, board_pairs(board, det.ids.tolist()), index, options))
    if not views:
        raise CheckError(
            f"no {board.squares_x}x{board.squares_y} ChArUco board ({board.dictionary}) with at least {MIN_CORNERS} "
            f"corners in {len(missed)} frame(s); show the whole board to the camera in good light, and give the "
            "board options it was printed with (--squares, --square-mm, --marker-mm, --dictionary)"
        )
    return CheckResult(board, tuple(pairs), tuple(views), tuple(missed), tuple(dets), fx_b)


def _mean(values: Iterable[float]) -> float | None:
    v = np.asarray(list(values), np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


def figures(result: CheckResult) -> dict:
    """The check's numbers (JSON-ready; lengths in m, errors in % of the true length)."""
    pr = result.pairs
    if not pr:
        raise CheckError("the board was found but no corner pair could be measured (no valid disparity on it); "
                         "add light or texture, or move closer")
    true = np.array([p.pair.length_m for p in pr])
    meas = np.array([p.measured_m for p in pr])
    acc = np.array([p.accuracy for p in pr])
    err = np.array([p.error_pct for p in pr])
    half = np.array([(p.interval_m[1] - p.interval_m[0]) / 2 for p in pr]) / meas * 100.0
    # Pairs share corners, so their errors are not independent: the standard error counts corners, not pairs.
    n_eff = max(int(np.mean([v.n_corners for v in result.views])), 2)
    sq = np.array([p.pair.squares for p in pr])
    per_length = {}
    for lo, hi, label in LENGTH_BINS:
        sel = (sq >= lo) & (sq < hi)
        if sel.any():
            per_length[label] = {"n": int(sel.sum()), "mean_accuracy": float(acc[sel].mean()),
                                 "bias_pct": float(np.median(err[sel])), "spread_pct": _mad(err[sel]),
                                 "interval_pm_pct": float(np.median(half[sel]))}
    # error_m = k * length + c: a scale (k) against a fixed end-point offset (c)
    k, c = robust_line(true, meas - true)
    # A scale error is read on the long pairs, where end-point noise is small against the length.
    long_pairs = sq >= LONG_SQUARES if np.sum(sq >= LONG_SQUARES) >= 10 else np.ones(len(sq), bool)
    err_long = err[long_pairs]
    frames_long = np.array([p.frame for p in pr])[long_pairs]
    spread = _frame_spread([p for p, keep in zip(pr, long_pairs) if keep])
    v = result.views
    ratio = _mean(x.depth_ratio for x in v)
    return {
        "board": {"squares": f"{result.board.squares_x}x{result.board.squares_y}",
                  "square_mm": result.board.square_m * 1000, "marker_mm": result.board.marker_m * 1000,
                  "dictionary": result.board.dictionary},
        "frames": len(v) + len(result.missed_frames),
        "frames_with_board": len(v),
        "pairs": len(pr),
        "mean_accuracy": float(acc.mean()),
        "long_mean_accuracy": float(acc[long_pairs].mean()),
        "median_accuracy": float(np.median(acc)),
        # The median over the long pairs: short pairs on a contended patch of disparity have a heavy
        # tail that a mean follows, and end-point errors weigh most on them.
        "bias_pct": float(np.median(err_long)),
        "bias_se_pct": 1.2533 * _mad(err_long) / math.sqrt(n_eff),
        "bias_pairs": int(long_pairs.sum()),
        "mean_error_pct": float(err.mean()),
        "spread_pct": _mad(err),
        "scale_pct": float(100.0 * k),
        "offset_mm": float(1000.0 * c),
        "per_length": per_length,
        "good_share": float(np.mean([p.quality == "good" for p in pr])),
        "interval_coverage": float(np.mean([p.covered for p in pr])),
        # measured: 1.96 x the robust spread of the long pairs' errors, frame noise included
        "expected_pm_pct": 1.96 * _mad(err_long),
        "interval_pm_pct": float(np.median(half[long_pairs])),  # what the reported intervals claim
        "distance_m": _mean(x.distance_m for x in v),
        "tilt_deg": _mean(x.tilt_deg for x in v),
        "px_per_square": _mean(x.px_per_square for x in v),
        "fill_rate": _mean(x.fill_rate for x in v),
        "plane_rms_mm": _mm(_mean(x.plane_rms_m for x in v)),
        "plane_noise_mm": _mm(_mean(x.plane_noise_m for x in v)),
        "plane_noise_px": _mean(x.plane_noise_px for x in v),
        "outlier_share": _mean(x.outlier_share for x in v),
        "depth_vs_pose_pct": None if ratio is None else 100.0 * (ratio - 1.0),
        "disparity_px": _mean(x.disparity_px for x in v),
        "fx_baseline": result.fx_baseline,  # fx * B (px m) of the frames: depth = fx_baseline / disparity
        "frame_spread_mm": spread[0],
        "frame_spread_pct": spread[1],
        # per frame, the bias as above (median of the long pairs' errors)
        "frame_bias_pct": [float(np.median(err_long[frames_long == x.frame])) for x in v if np.any(frames_long == x.frame)],
    }


def _mad(v: np.ndarray) -> float:
    """1.4826 x the median absolute deviation: a standard deviation that a few wild values do not set."""
    return float(1.4826 * np.median(np.abs(v - np.median(v)))) if len(v) else math.nan


def _mm(m: float | None) -> float | None:
    return None if m is None else 1000.0 * m


def _frame_spread(pr: Sequence[PairResult]) -> tuple[float | None, float | None]:
    by_pair: dict[tuple[int, int], list[float]] = {}
    for p in pr:
        by_pair.setdefault((p.pair.id1, p.pair.id2), []).append(p.measured_m)
    stds = [(np.std(v, ddof=1), np.mean(v)) for v in by_pair.values() if len(v) >= 2]
    if not stds:
        return None, None
    return float(1000.0 * np.median([s for s, _ in stds])), float(100.0 * np.median([s / m for s, m in stds]))


@dataclass(frozen=True)
class Finding:
    """One conclusion: what was measured, its likely cause (an inference, not a measurement), what to do.
    severity: "info" | "warn" | "fail"."""

    measured: str
    cause: str = ""
    action: str = ""
    severity: str = "info"


# Thresholds of the verdict. A scale bias matters when it exceeds both 0.5 % (what a good stereo
# calibration achieves) and three standard errors; fill rate and plane RMS follow the Depth Quality
# Tool's usual reading (a flat, lit target fills > 80 %; RMS < 1 % of distance is typical of stereo).
BIAS_PCT = 0.5
SHORT_A = 95.0  # a short length scoring below this (and 3 points below the long ones) is worth a word
LOW_A = 95.0  # long lengths below this: the check fails
FILL_LOW, FILL_OK = 0.5, 0.8
PLANE_RMS_PCT = 1.0
NOISE_PX = 0.5  # disparity noise of a sound matcher on a flat, lit board is a few tenths of a pixel
OUTLIER_SHARE = 0.1
FAR_PM_PCT = 2.0
FAR_DISPARITY_PX = 25.0  # a quarter pixel is 1 % of depth here
SMALL_PX_PER_SQUARE = 15.0


def findings(fig: dict) -> list[Finding]:
    """The verdict: measured conclusions, each with a likely cause and what to do (module docstring)."""
    out: list[Finding] = []
    z = fig["distance_m"] or math.nan
    b, se = fig["bias_pct"], fig["bias_se_pct"]
    sq_mm = fig["board"]["square_mm"]
    if abs(b) >= BIAS_PCT and abs(b) > 3 * se:
        biases = [v["bias_pct"] for v in fig["per_length"].values() if v["n"] >= 3]
        tol = max(BIAS_PCT, 0.35 * abs(b))
        # a scale: the robust slope says the same as the median, and the bias is no end-point offset
        # (the 2-square and longer bins agree; one-square pairs are too noisy to judge)
        firm = [v["bias_pct"] for key, v in fig["per_length"].items() if v["n"] >= 3 and key != LENGTH_BINS[0][2]]
        bins_agree = abs(fig["scale_pct"] - b) <= tol and all(abs(x - b) <= tol for x in firm)
        dz = fig["depth_vs_pose_pct"]
        depth_agrees = dz is not None and abs(dz - b) <= tol  # the pose does not use the baseline
        word = "long" if b > 0 else "short"
        span = f" ({min(biases):+.1f} to {max(biases):+.1f} % across lengths)" if biases else ""
        measured = f"lengths read {abs(b):.1f} % {word} at {z:.1f} m ({fig['bias_pairs']} long pairs, ±{1.96 * se:.1f} %){span}"
        if depth_agrees:
            out.append(Finding(
                measured=measured + f"; stereo depth reads {dz:+.1f} % against the board's pose from the image alone"
                         + (" - the same at every length: a scale error" if bins_agree else ": a scale error"),
                cause=f"the baseline in the calibration is probably off by about {b:+.1f} % (it scales every depth and "
                      "length alike, and the pose does not use it); a board printed at another scale than --square-mm "
                      "gives the same signature",
                action=f"measure a printed square with a ruler: if it is {sq_mm:g} mm, recalibrate (depthruler calibrate) "
                       f"or scale the calibration's T by {1 / (1 + b / 100):.4f}; otherwise pass the measured --square-mm",
                severity="fail" if abs(b) >= 2.0 else "warn",
            ))
        elif bins_agree:
            out.append(Finding(
                measured=measured + f" - the same at every length, but stereo depth agrees with the board's pose "
                         f"({dz:+.1f} %)" if dz is not None else measured,
                cause="a scale in the lengths that depth does not share: not the baseline; the corner positions or the "
                      "measurement method",
                action="check the image is sharp and the board flat; report it with the check's PNG",
                severity="warn",
            ))
        else:
            out.append(Finding(
                measured=measured + f"; the error is mostly a fixed {fig['offset_mm']:+.1f} mm per length, not a scale",
                cause="the end points are pulled (disparity smoothing or edge fattening at the corners, "
                      "or a detection offset), which matters most on short lengths",
                action="expect short measurements to be off by that much; check focus and the disparity filter settings",
                severity="warn",
            ))
    fill = fig["fill_rate"]
    if fill is not None and fill < FILL_OK:
        out.append(Finding(
            measured=f"fill rate {100 * fill:.0f} %: that share of the board has valid disparity",
            cause="too little light or texture for the stereo matcher (the board's plain squares and margins)",
            action="add light or texture (switch on the IR projector if the camera has one)",
            severity="warn" if fill < FILL_LOW else "info",
        ))
    pm = fig["expected_pm_pct"]
    d = fig["disparity_px"]
    if pm > FAR_PM_PCT or (d is not None and d < FAR_DISPARITY_PX and pm > 1.0):
        closer = z / pm if math.isfinite(z) and pm > 0 else math.nan  # the error grows about with distance
        out.append(Finding(
            measured=f"95 % of long lengths fall within ±{pm:.1f} % of the truth at {z:.1f} m (disparity {d:.0f} px on the board)",
            cause=f"the board is far for this baseline: a quarter-pixel matching error is {25 / d:.1f} % of depth there"
                  if d and math.isfinite(d) else "the board is far for this baseline",
            action=f"expect ±{pm:.1f} % at this distance" + (f"; for about ±1 % measure within {closer:.1f} m" if pm > 1 else ""),
            severity="info",
        ))
    px = fig["px_per_square"]
    if px is not None and px < SMALL_PX_PER_SQUARE:
        out.append(Finding(
            measured=f"the board's squares are {px:.0f} px wide in the image",
            cause="corners of a small board are found less precisely, which adds error to every pair",
            action="move closer or print a larger board (depthruler calibrate --board-png)",
            severity="warn",
        ))
    noise, rms, outl = fig["plane_noise_mm"], fig["plane_rms_mm"], fig["outlier_share"]
    if noise is not None and math.isfinite(z) and noise / (10 * z) > PLANE_RMS_PCT:
        noisy = fig["plane_noise_px"] > NOISE_PX
        out.append(Finding(
            measured=f"depth noise {noise:.1f} mm ({noise / (10 * z):.1f} % of the distance, {fig['plane_noise_px']:.2f} px "
                     "of disparity) about the flat board's plane",
            cause="noisy matching: low light, a weakly textured or shiny board, or a bent board" if noisy else
                  "the distance: the matching itself is precise, but a fraction of a pixel is a lot of depth this far",
            action="improve the light, flatten the board, or move closer" if noisy else "move closer for less depth noise",
            severity="warn" if noisy else "info",
        ))
    if outl is not None and outl > OUTLIER_SHARE:
        out.append(Finding(
            measured=f"{100 * outl:.0f} % of the board's depth is more than 3 sigma off its plane "
                     f"(plane-fit RMS {rms:.1f} mm against {noise:.1f} mm noise)",
            cause="wrong stereo matches (repetitive or plain areas, reflections); the robust method rejects most of them",
            action="expect single clicks on such patches to be off; more texture or light helps",
            severity="info",
        ))
    cov = fig["interval_coverage"]
    if cov < 0.8:
        out.append(Finding(
            measured=f"the true length fell inside the reported 95 % interval for {100 * cov:.0f} % of pairs",
            cause="the intervals do not cover this camera's errors" + (" (the bias above is not in them)" if any(
                f.severity != "info" and "lengths read" in f.measured for f in out) else ""),
            action="fix the bias first; until then read the ± as a lower bound",
            severity="warn",
        ))
    sp = fig["frame_spread_pct"]
    if sp is not None and sp > 2 * pm / 1.96:  # clearly more than the noise within one frame
        out.append(Finding(
            measured=f"a length varies by {sp:.2f} % (1 sigma) from frame to frame",
            cause="the camera or board moved, or the light flickers",
            action="hold camera and board still; measure on a frozen frame",
            severity="info",
        ))
    short = fig["per_length"].get(LENGTH_BINS[0][2])
    long_a = fig["long_mean_accuracy"]
    if short and short["mean_accuracy"] < min(SHORT_A, long_a - 3.0):
        px_short = fig["px_per_square"]
        out.append(Finding(
            measured=f"short lengths (1 square, {px_short:.0f} px) score A {short['mean_accuracy']:.1f} "
                     f"(bias {short['bias_pct']:+.1f} %) against {long_a:.1f} for 3 squares or more",
            cause="a short segment holds few disparity samples, and each end's depth error is a large share of it",
            action="measure objects that span 100 px or more in the image: move closer for small ones",
            severity="warn",
        ))
    if long_a < LOW_A and not any(f.severity == "fail" for f in out):
        out.append(Finding(measured=f"even lengths of 3 squares or more score only A {long_a:.1f}", severity="fail",
                           cause="see the findings above (light, texture, distance)",
                           action="fix those, then check again"))
    return out


TREND_MIN_CHECKS = 3
TREND_MIN_RATIO = 1.5  # farthest / nearest distance among the checks


def trend_findings(history: Sequence[dict], fig: dict) -> list[Finding]:
    """What the earlier checks of the same camera and calibration add (``history``: their records with
    "figures"): whether the bias stays the same across distances (a baseline: ``Z = fx B / d`` scales
    every distance alike) or grows with distance (a disparity offset delta: the relative error of
    ``fx B / (d + delta)`` is about ``-delta / d = -delta Z / (fx B)``, proportional to Z)."""
    pts = [(h["figures"].get("distance_m"), h["figures"].get("bias_pct"), h["figures"].get("fx_baseline"))
           for h in history if h.get("figures")] + [(fig["distance_m"], fig["bias_pct"], fig["fx_baseline"])]
    pts = [p for p in pts if all(v is not None and math.isfinite(v) for v in p)]
    if len(pts) < TREND_MIN_CHECKS:
        return []
    z, bias, fxb = (np.array(v, np.float64) for v in zip(*pts))
    if z.max() / z.min() < TREND_MIN_RATIO:
        return []
    slope, icpt = np.polyfit(z, bias, 1)
    change = slope * (z.max() - z.min())
    where = f"{len(pts)} checks from {z.min():.1f} to {z.max():.1f} m"
    if abs(change) >= BIAS_PCT:
        delta = -slope * float(np.median(fxb)) / 100.0
        return [Finding(
            measured=f"over {where} the bias goes from {icpt + slope * z.min():+.1f} to {icpt + slope * z.max():+.1f} %: "
                     "it grows with distance",
            cause=f"a disparity offset of about {delta:+.2f} px (the calibration's principal points or doffs, or the "
                  "rectification), not only the baseline, which would read the same % at every distance",
            action="recalibrate with board views spread over the working distances",
            severity="warn",
        )]
    if abs(float(np.mean(bias))) >= BIAS_PCT:
        return [Finding(
            measured=f"over {where} the bias stays at {np.mean(bias):+.1f} % (±{abs(change) / 2:.1f})",
            cause="a scale that does not depend on distance: the baseline (or the board's printed size), not a "
                  "disparity offset",
            action="see the baseline finding above",
            severity="info",
        )]
    return []


def status(found: Sequence[Finding]) -> str:
    """"ok" (nothing to act on), "check" (a warning) or "poor" (a failing figure)."""
    severities = {f.severity for f in found}
    return "poor" if "fail" in severities else "check" if "warn" in severities else "ok"


def report(result: CheckResult, history: Sequence[dict] = ()) -> dict:
    """figures + findings + status, JSON-ready; ``history``: earlier check records of the same camera and
    calibration, for :func:`trend_findings`."""
    fig = figures(result)
    found = findings(fig) + trend_findings(history, fig)
    return {"status": status(found), "figures": fig, "findings": [asdict(f) for f in found],
            "missed_frames": list(result.missed_frames)}
