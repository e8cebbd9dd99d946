"""The board side of `depthruler doctor`: when a printed ChArUco board is in view, a short `depthruler check`.

The board is the one given (``--squares``, ``--square-mm``, ...), else the simulator's own when the
source is its "charuco" scene, else the default printed by ``depthruler calibrate --board-png``.
Markers of the dictionary in view without that board means the options do not match the print.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2

from device import SourceError, source_config
from device.calibration.board import BoardSpec
from measure import Frame

from check.doctor.findings import Finding
from check.errors import CheckError

SEVERITY = {"ok": "pass", "check": "warn", "poor": "fail"}


def source_board(spec: str) -> BoardSpec | None:
    """The board a source shows by construction: the simulator's "charuco" scene; None for any other."""
    try:
        cfg = source_config(spec)
    except SourceError:
        return None
    if getattr(cfg, "scene", None) == "charuco" and callable(getattr(cfg, "charuco", None)):
        return BoardSpec(*cfg.charuco())
    return None


def markers_in_view(image, dictionary: str) -> int:
    """How many ArUco markers of ``dictionary`` the image shows."""
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)))
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    _, ids, _ = detector.detectMarkers(gray)
    return 0 if ids is None else len(ids)


def board_finding(frames: Sequence[Frame], board: BoardSpec) -> Finding:
    """"board": the check (:func:`check.run.check_frames`) on ``frames`` when ``board`` is in view; skip when
    no marker is; warn when markers are but not this board."""
    from check.run import check_frames

    if not frames:
        return Finding("board", "skip", "no frame")
    name = f"{board.squares_x}x{board.squares_y} board of {board.square_m * 1000:g} mm squares ({board.dictionary})"
    seen = max(markers_in_view(f.image, board.dictionary) for f in frames)
    if seen == 0:
        return Finding("board", "skip", f"no {board.dictionary} marker in view: no board check",
                       "to check lengths, hold a printed board in view (depthruler calibrate --board-png board.png) "
                       "and pass its --squares/--square-mm/--marker-mm", {"markers": 0})
    try:
        done = check_frames(list(frames), board, picture=False, title="depthruler doctor")
    except CheckError as exc:
        return Finding("board", "warn", f"{seen} {board.dictionary} markers in view, but not the {name}: {exc}",
                       "pass the options the board was printed with (--squares, --square-mm, --marker-mm, --dictionary)",
                       {"markers": seen})
    rep = done.report
    fig = rep["figures"]
    measured = (f"{name} at {fig['distance_m']:.2f} m: {fig['pairs']} pairs, mean accuracy {fig['mean_accuracy']:.1f}, "
                f"bias {fig['bias_pct']:+.2f} %, truth inside the 95 % interval {100 * fig['interval_coverage']:.0f} %")
    actions = [f["action"] for f in rep["findings"] if f["severity"] != "info" and f["action"]]
    figures = {k: fig[k] for k in ("pairs", "distance_m", "mean_accuracy", "bias_pct", "spread_pct", "interval_coverage")}
    return Finding("board", SEVERITY.get(rep["status"], "warn"), measured, "; ".join(actions),
                   {**figures, "markers": seen, "status": rep["status"]})
