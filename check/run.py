"""`depthruler check`: how accurate are lengths from this camera, here, today, against a printed ChArUco board.

Per frame: find the board in the colour image (OpenCV's ``CharucoDetector``, sub-pixel corners; a board
in the legacy pattern is recognised: device.calibration.board); measure every pair of known length as
if clicked at its corners, which are exact clicks (``click_px = 0``: the interval is the depth's alone,
so a camera whose errors it does not cover shows) (:mod:`check.pairs`); take the board as a depth target
(:mod:`check.target`). Over the frames: the figures (:mod:`check.figures`), the findings and a status
(:mod:`check.findings`, worded for the frames' source kind: :mod:`check.advice`). :func:`check_frames` does it all on frames a caller
holds (the CLI, the service) and also draws the picture (:mod:`check.plot`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, replace

from device.calibration.board import BoardDetector, BoardSpec, Detection
from measure import Frame, MeasureOptions

from check.errors import CheckError
from check.figures import figures
from check.findings import findings, status, trend_findings
from check.pairs import PairResult, board_pairs, measure_pairs
from check.result import CheckResult
from check.target import BoardView, board_view

MIN_CORNERS = 6
CORNER_CLICK_PX = 0.0  # detected corners are the program's exact clicks (MeasureOptions.click_px)


def run_check(frames: Iterable[Frame], board: BoardSpec, options: MeasureOptions = MeasureOptions()) -> CheckResult:
    """The check on ``frames`` (each with its colour image and registered disparity) of ``board``.

    The pairs are measured with ``options`` at ``click_px = CORNER_CLICK_PX`` whatever it says (the clicks
    are detected corners). Raises :class:`CheckError` when no frame shows at least ``MIN_CORNERS``
    corners of the board.
    """
    options = replace(options, click_px=CORNER_CLICK_PX)
    detector = BoardDetector(board)
    pairs: list[PairResult] = []
    views: list[BoardView] = []
    dets: list[Detection] = []
    missed: list[int] = []
    fx_b = math.nan
    kind = None
    for index, frame in enumerate(frames):
        det = detector.detect(frame.image)
        board = detector.board  # the legacy pattern once the detector has found it
        if det is None or len(det.ids) < MIN_CORNERS:
            missed.append(index)
            continue
        views.append(board_view(board, det, frame, index))
        dets.append(det)
        if not views[1:]:
            fx_b = frame.camera.fx * frame.baseline_m
            kind = frame.meta.get("source") if isinstance(frame.meta.get("source"), str) else None
        pairs.extend(measure_pairs(frame, det, board_pairs(board, det.ids.tolist()), index, options))
    if not views:
        raise CheckError(
            f"no {board.squares_x}x{board.squares_y} ChArUco board ({board.dictionary}) with at least {MIN_CORNERS} "
            f"corners in {len(missed)} frame(s); show the whole board to the camera in good light, and give the "
            "board options it was printed with (--squares, --square-mm, --marker-mm, --dictionary, or --board PAPER; "
            "--legacy for a board printed by OpenCV before 4.6)"
        )
    return CheckResult(board, tuple(pairs), tuple(views), tuple(missed), tuple(dets), fx_b, detector.switched, kind)


def report(result: CheckResult, history: Sequence[dict] = ()) -> dict:
    """figures + findings + status, JSON-ready; ``history``: earlier check records of the same camera and
    calibration, for :func:`trend_findings`. The advice fits ``result.source_kind`` (:mod:`check.advice`)."""
    fig = figures(result)
    found = findings(fig, result.source_kind) + trend_findings(history, fig, result.source_kind)
    return {"status": status(found), "figures": fig, "findings": [asdict(f) for f in found],
            "missed_frames": list(result.missed_frames)}


@dataclass(frozen=True)
class BoardCheck:
    """One board check on frames a caller holds: what was measured, the report, and the picture."""

    result: CheckResult
    report: dict  # status, figures, findings, missed_frames (JSON-ready; see :func:`report`)
    png: bytes | None  # the picture of :func:`check.plot.render_check_png`; None when not asked for
    frame: Frame  # the frame the picture shows (the first one with the board)


def check_frames(frames: Sequence[Frame], board: BoardSpec, *, earlier: Sequence[dict] = (), picture: bool = True,
                 title: str = "depthruler check", options: MeasureOptions = MeasureOptions()) -> BoardCheck:
    """The whole check on ``frames`` of ``board``, without a command line: :func:`run_check`, :func:`report`
    (``earlier``: records of earlier checks of the same camera and calibration) and, with ``picture``,
    the PNG. Raises :class:`CheckError` when no frame shows the board or nothing on it can be measured."""
    from check.plot import render_check_png

    if not frames:
        raise CheckError("no frame to check; give at least one frame of the board")
    result = run_check(frames, board, options)
    rep = report(result, earlier)
    shown = frames[result.views[0].frame]
    return BoardCheck(result, rep, render_check_png(shown, result, rep, title) if picture else None, shown)
