"""The ChArUco board options of `depthruler calibrate` and `depthruler check`: squares and sizes, or a paper preset."""

from __future__ import annotations

import math

import typer

PAPERS = ("a4", "letter")  # check.boards.PAPERS_MM, named here so that --help imports no OpenCV


def squares_option():  # noqa: ANN201 — typer's OptionInfo; one new object per command
    return typer.Option("11x8", "--squares", help="ChArUco squares across x down (as printed by calibrate).")


def square_mm_option():  # noqa: ANN201
    return typer.Option(30.0, "--square-mm", help="Printed square side in mm (measure it with a ruler).")


def marker_mm_option():  # noqa: ANN201
    return typer.Option(22.0, "--marker-mm", help="Printed marker side in mm.")


def dictionary_option():  # noqa: ANN201
    return typer.Option("DICT_5X5_100", "--dictionary", help="ArUco dictionary of the board.")


def paper_option(help: str):  # noqa: ANN201, A002 — typer's keyword
    return typer.Option(None, "--board", "--paper", metavar="|".join(PAPERS), help=help)


def legacy_option():  # noqa: ANN201
    return typer.Option(False, "--legacy", help="The board is in OpenCV's legacy pattern (printed by OpenCV before 4.6 "
                        "or a generator that follows it; differs with an even number of rows). Without it such a board "
                        "is still tried as legacy when its markers show but no corners.")


BOARD_OPTIONS = ("squares", "square_mm", "marker_mm", "dictionary", "board_paper")  # the parameters that describe a board


def described(ctx: typer.Context) -> bool:
    """Whether the command line gave any of :data:`BOARD_OPTIONS` (else the source's own board is looked for)."""
    return any(getattr(ctx.get_parameter_source(n), "name", "DEFAULT") != "DEFAULT" for n in BOARD_OPTIONS)


def parse_squares(text: str) -> tuple[int, int]:
    """``COLSxROWS`` (e.g. ``11x8``) as two ints; typer.BadParameter otherwise."""
    try:
        x, _, y = text.lower().partition("x")
        return int(x), int(y)
    except ValueError as exc:
        raise typer.BadParameter(f"{text!r} is not COLSxROWS, e.g. 11x8", param_hint="--squares") from exc


def board_from_options(ctx: typer.Context, squares: str, square_mm: float, marker_mm: float, dictionary: str, paper: str | None,
                       legacy: bool = False):
    """The board the options describe and the PNG margin (mm) to print it with (None: the printer's default).

    With ``paper`` the squares are sized to fit it (:func:`check.boards.paper_board`) and giving
    ``--square-mm`` or ``--marker-mm`` as well is an error; without, both sizes must be positive."""
    from dataclasses import replace

    from check.boards import paper_board
    from check.errors import CheckError
    from device.calibration.board import BoardSpec

    sx, sy = parse_squares(squares)
    if paper is not None:
        given = [f"--{n.replace('_', '-')}" for n in ("square_mm", "marker_mm") if getattr(ctx.get_parameter_source(n), "name", "DEFAULT") != "DEFAULT"]
        if given:
            raise typer.BadParameter(f"--board {paper} sets the sizes; leave out {' and '.join(given)}", param_hint="--board")
        try:
            preset = paper_board(paper, sx, sy, dictionary)
        except CheckError as exc:
            raise typer.BadParameter(str(exc), param_hint="--board") from None
        return replace(preset.board, legacy=legacy), preset.margin_mm
    for name, value in (("--square-mm", square_mm), ("--marker-mm", marker_mm)):
        if not (math.isfinite(value) and value > 0):
            raise typer.BadParameter(f"{value:g} is not a length; give the printed side in mm (measure it with a ruler)", param_hint=name)
    return BoardSpec(sx, sy, square_mm / 1000.0, marker_mm / 1000.0, dictionary, legacy), None
