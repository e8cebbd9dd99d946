"""Pairs of board corners with known lengths, and each pair measured as if clicked at its corners.

Chessboard corner k of a board of ``squares_x`` x ``squares_y`` squares sits at ``(i, j) * square``
on the sheet, i = k mod (squares_x - 1), j = k div (squares_x - 1). The pairs are every two detected
corners on one row, one column or one 45 degree diagonal, and the two full-board diagonals: from one
square (``square_m``) to the board's size. A pair is measured with the run's options (default
``MeasureOptions()``) and scored with Eq. 8 (``measure.metrics.accuracy``), the signed error in %
of the true length and whether the true length lies inside the reported 95 % interval.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from device.calibration.board import BoardSpec, Detection
from measure import Frame, MeasureError, MeasureOptions, measure_distance
from measure.metrics import accuracy, signed_error_pct


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


def measure_pairs(frame: Frame, det: Detection, pairs: Iterable[CornerPair], index: int = 0,
                  options: MeasureOptions = MeasureOptions()) -> list[PairResult]:
    """Each pair measured as if clicked at its two detected corners (metres, pixels); see the module docstring."""
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
