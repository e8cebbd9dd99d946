"""The ChArUco calibration board: its description (squares, sizes in metres, dictionary, pattern), a printable
PNG at its physical size, corner detection, and rendering a view of it (to synthesise calibration data).

Boards printed by OpenCV before 4.6 (and by many online generators) use the *legacy* pattern: with an
even number of rows the chessboard is shifted by one square against today's, so today's detector finds
the markers but no corner. ``BoardSpec(legacy=True)`` (``--legacy``) describes such a board, and
:class:`BoardDetector` retries with the legacy pattern by itself when markers are found but few corners.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from device.errors import CalibrationError


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares across and down, square and marker side in metres, ArUco dictionary."""

    squares_x: int = 11
    squares_y: int = 8
    square_m: float = 0.030
    marker_m: float = 0.022
    dictionary: str = "DICT_5X5_100"
    legacy: bool = False  # OpenCV's pattern before 4.6 (differs from today's with an even number of rows)

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise CalibrationError(f"board {self.squares_x}x{self.squares_y} squares is too small; use at least 3x3")
        if not (0 < self.marker_m < self.square_m):
            raise CalibrationError(
                f"marker side {self.marker_m} m must be positive and smaller than the square side {self.square_m} m"
            )
        if not hasattr(cv2.aruco, self.dictionary):
            raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r}; use e.g. DICT_5X5_100, DICT_4X4_50")

    def board(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)
        board.setLegacyPattern(bool(self.legacy))
        return board

    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)


def write_board_png(board: BoardSpec, out: str | Path, dpi: float = 300.0, margin_mm: float = 10.0) -> tuple[Path, float, float]:
    """Write the printable ChArUco board that :func:`calibrate_stereo` expects; returns (path, width mm, height mm).

    The PNG is rendered at ``dpi`` with a white margin of ``margin_mm`` around the squares and
    carries its physical resolution (a pHYs chunk), so printing at 100 % ("actual size") gives
    squares of ``board.square_m``. The returned size is the whole sheet, margins included.
    """
    import struct
    import zlib

    if not (72 <= dpi <= 1200):
        raise CalibrationError(f"dpi={dpi} must lie in 72..1200")
    # Whole pixels per square, and the PNG's resolution set from them, so a square prints at exactly
    # its size (the effective dpi differs from the asked one by less than half a pixel per square).
    square_px = int(round(board.square_m * 1000.0 * dpi / 25.4))
    px_per_mm = square_px / (board.square_m * 1000.0)
    margin_px = int(round(margin_mm * px_per_mm))
    w = board.squares_x * square_px + 2 * margin_px
    h = board.squares_y * square_px + 2 * margin_px
    image = board.board().generateImage((w, h), marginSize=margin_px, borderBits=1)
    ok, png = cv2.imencode(".png", image)
    if not ok:
        raise CalibrationError("OpenCV could not encode the board as PNG")
    data = png.tobytes()
    ppm = int(round(px_per_mm * 1000.0))
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)  # pixels per metre, unit = metre
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    ihdr_end = 8 + 8 + 13 + 4  # signature, IHDR length + type, IHDR data, CRC
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(data[:ihdr_end] + chunk + data[ihdr_end:])
    return out, w / px_per_mm, h / px_per_mm


@dataclass(frozen=True)
class Detection:
    """Board corners found in one image: ids into the board's chessboard corners, pixel positions."""

    ids: np.ndarray  # (N,) int
    corners: np.ndarray  # (N, 2) float32 pixels


def detect_board(detector: cv2.aruco.CharucoDetector, image: np.ndarray) -> Detection | None:
    """The board's chessboard corners in ``image`` (BGR or grey), sub-pixel; None when none is found."""
    return _detect(detector, image)[0]


def _detect(detector: cv2.aruco.CharucoDetector, image: np.ndarray) -> tuple[Detection | None, int]:
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners, ids, _, marker_ids = detector.detectBoard(gray)
    markers = 0 if marker_ids is None else len(marker_ids)
    if corners is None or ids is None or len(ids) == 0:
        return None, markers
    return Detection(ids=np.asarray(ids).ravel().astype(np.int32), corners=np.asarray(corners, np.float32).reshape(-1, 2)), markers


class BoardDetector:
    """Finds one board in images, and finds out whether it is printed in the legacy pattern.

    :meth:`detect` uses the board as described; when an image shows markers but fewer corners than
    markers (a legacy board read as today's gives none) and the board is not already legacy, it tries
    the legacy pattern, and if that finds more corners it keeps it: :attr:`board` is then the board
    with ``legacy=True``, for the later images and for the caller to report.
    """

    def __init__(self, board: BoardSpec) -> None:
        self.board = board
        self._detector = cv2.aruco.CharucoDetector(board.board())
        self.switched = False  # True once the legacy pattern was found instead of the one described

    def detect(self, image: np.ndarray) -> Detection | None:
        """The board's corners in ``image`` (:func:`detect_board`), with the legacy retry above."""
        det, markers = _detect(self._detector, image)
        found = 0 if det is None else len(det.ids)
        if self.board.legacy or self.board.squares_y % 2 or markers == 0 or found >= markers:
            return det  # with an odd number of rows both patterns are the same board
        legacy = replace(self.board, legacy=True)
        detector = cv2.aruco.CharucoDetector(legacy.board())
        other, _ = _detect(detector, image)
        if other is None or len(other.ids) <= found:
            return det
        self.board, self._detector, self.switched = legacy, detector, True
        return other


def render_board_view(
    board_image: np.ndarray,
    pixels_per_m: float,
    margin_px: int,
    K: np.ndarray,
    rvec: Sequence[float],
    tvec: Sequence[float],
    size: tuple[int, int],
    background: int = 128,
    supersample: int = 1,
) -> np.ndarray:
    """Image of a flat board seen by a distortion-free camera: a homography warp of the board image.

    The board image is ``BoardSpec.board().generateImage`` at ``pixels_per_m`` with ``margin_px``;
    a board point (X, Y, 0) (metres) lies at board pixel ``margin + p X - 0.5`` (pixel-centre
    convention). The camera sees it at ``K [r1 r2 t] (X, Y, 1)``, so the warp is
    ``H = K [r1 r2 t] A^-1`` with A the board-pixel map. ``supersample`` renders at that factor
    and averages pixel blocks down, as a sensor integrates light over each pixel (less aliasing
    than sampling the board once per pixel). Used to synthesise calibration data.
    """
    R, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
    Rt = np.column_stack([R[:, 0], R[:, 1], np.asarray(tvec, np.float64).reshape(3)])
    A = np.array([[pixels_per_m, 0, margin_px - 0.5], [0, pixels_per_m, margin_px - 0.5], [0, 0, 1]])
    s = int(supersample)
    up = np.array([[s, 0, (s - 1) * 0.5], [0, s, (s - 1) * 0.5], [0, 0, 1]])  # pixel-centre convention
    H = up @ np.asarray(K, np.float64) @ Rt @ np.linalg.inv(A)
    big = cv2.warpPerspective(board_image, H, (size[0] * s, size[1] * s), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    return big if s == 1 else cv2.resize(big, size, interpolation=cv2.INTER_AREA)
