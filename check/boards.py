"""Printable board presets: the largest ChArUco board of given squares that prints on A4 or US Letter.

A preset's squares are whole millimetres (a ruler reads them), as large as the sheet allows once
the printer's unprintable border (:data:`PRINTER_MARGIN_MM` per side) and the PNG's own white
margin (:data:`SHEET_MARGIN_MM`) are taken off, in landscape or portrait, whichever gives larger
squares; the markers are :data:`MARKER_RATIO` of a square, rounded down to a whole millimetre.
``depthruler calibrate --board-png OUT --board a4`` prints it and ``depthruler check --board a4``
checks against it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from device.calibration.board import BoardSpec

from check.errors import CheckError

PAPERS_MM = {"a4": (297.0, 210.0), "letter": (279.4, 215.9)}  # ISO 216 A4, ANSI US Letter (8.5 x 11 in)
PRINTER_MARGIN_MM = 6.35  # a quarter inch: the widest unprintable border of common office printers
SHEET_MARGIN_MM = 5.0  # white around the squares inside the PNG (the paper beyond it is white too)
MARKER_RATIO = 0.75


@dataclass(frozen=True)
class PaperBoard:
    """A board sized for a paper: the board, the PNG margin to print it with (mm), the paper's name and size (mm)."""

    board: BoardSpec
    margin_mm: float
    paper: str
    paper_mm: tuple[float, float]

    def sheet_mm(self) -> tuple[float, float]:
        """Width and height (mm) of the printed sheet: the squares and the PNG's margin."""
        return (self.board.squares_x * self.board.square_m * 1000 + 2 * self.margin_mm,
                self.board.squares_y * self.board.square_m * 1000 + 2 * self.margin_mm)  # fmt: skip


def paper_board(paper: str, squares_x: int = 11, squares_y: int = 8, dictionary: str = "DICT_5X5_100") -> PaperBoard:
    """The largest board of ``squares_x`` x ``squares_y`` whole-millimetre squares that prints on ``paper``
    ("a4" or "letter"); CheckError names the papers for another name, or asks for fewer squares."""
    size = PAPERS_MM.get(paper.strip().lower())
    if size is None:
        raise CheckError(f"unknown paper {paper!r}; use one of {', '.join(PAPERS_MM)}")
    room = [s - 2 * PRINTER_MARGIN_MM - 2 * SHEET_MARGIN_MM for s in size]
    square = max(math.floor(min(room[0] / squares_x, room[1] / squares_y)), math.floor(min(room[1] / squares_x, room[0] / squares_y)))
    marker = math.floor(MARKER_RATIO * square)
    if marker < 4:
        raise CheckError(f"{squares_x}x{squares_y} squares leave {square} mm per square on {paper}; use fewer squares (e.g. 7x5)")
    board = BoardSpec(squares_x, squares_y, square / 1000.0, marker / 1000.0, dictionary)
    return PaperBoard(board, SHEET_MARGIN_MM, paper.strip().lower(), size)


def papers_that_fit(width_mm: float, height_mm: float) -> list[str]:
    """The papers of :data:`PAPERS_MM` a sheet of ``width_mm`` x ``height_mm`` (margins included) prints
    on at 100 %, inside the printer's unprintable border, in either orientation."""
    def fits(w: float, h: float, paper: tuple[float, float]) -> bool:
        return w <= paper[0] - 2 * PRINTER_MARGIN_MM and h <= paper[1] - 2 * PRINTER_MARGIN_MM

    return [name for name, size in PAPERS_MM.items()
            if fits(width_mm, height_mm, size) or fits(height_mm, width_mm, size)]  # fmt: skip
