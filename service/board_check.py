"""The board check on frames of the ring (``POST /api/checks``): the page's "Check accuracy" button.

The frames are the one named and the ones received just before it (as "measure over N frames"); when
the ring holds fewer of them than asked, the check uses those and its record says so (``frames_note``).
The board is the one the request describes, else the source's own (the simulator's "charuco" scene),
else the default printed by ``depthruler calibrate --board-png``. The check's record goes into the
checks log with its picture beside it, as `depthruler check --db` would keep it.
"""

from __future__ import annotations

import secrets
from typing import Any

from check.doctor.board import source_board
from check.errors import CheckError
from check.record import check_record, earlier_checks
from check.run import check_frames
from device import SourceInfo
from device.calibration.board import BoardSpec
from device.errors import CalibrationError
from history.checks import append_check, checks_path, save_picture

from service.state import ServiceState


def board_of(described: dict[str, Any] | None, spec: str) -> BoardSpec:
    """The board to look for: ``described`` (squares_x, squares_y, square_mm, marker_mm, dictionary), else the source's."""
    if described is None:
        return source_board(spec) or BoardSpec()
    try:
        return BoardSpec(described["squares_x"], described["squares_y"], described["square_mm"] / 1000.0,
                         described["marker_mm"] / 1000.0, described["dictionary"])
    except CalibrationError as exc:
        raise CheckError(f"board: {exc}") from exc


def frames_note(used: int, asked: int, frame_id: int) -> str | None:
    """What the check's record and the page say when ``used`` of the ``asked`` frames were there (None: all were)."""
    if used >= asked:
        return None
    held = "no earlier frame" if used == 1 else "only 1 earlier frame" if used == 2 else f"only {used - 1} earlier frames"
    return f"used {used} of {asked} frames: the ring held {held} of this camera before frame {frame_id}"


def run_board_check(state: ServiceState, frame_id: int, n_frames: int, described: dict[str, Any] | None) -> dict[str, Any]:
    """Check the board on frame ``frame_id`` and the ``n_frames - 1`` before it (those the ring holds); the stored
    record, with ``id``, ``frame_id``, ``frame_ids`` (used, oldest first), ``frames_requested``, ``frames_note``
    (:func:`frames_note`, when fewer were used), ``board`` and ``png_url`` (the picture). Raises CheckError when no
    frame shows the board."""
    entry = state.ring.get(frame_id)
    used = list(reversed(state.ring.before(entry.id, n_frames - 1))) + [entry] if n_frames > 1 else [entry]
    spec = state.capture.spec
    board = board_of(described, spec)
    info = state.capture.info or SourceInfo(kind=spec.partition(":")[0], name=spec)
    log = checks_path(state.store.path)
    frames = [e.frame for e in used]
    done = check_frames(frames, board, earlier=earlier_checks(log, info, frames[0]), title=f"depthruler check: {spec}")
    check_id = secrets.token_hex(8)
    record = check_record(spec, info, done.frame, done.report)
    board_json = {"squares_x": board.squares_x, "squares_y": board.squares_y, "square_mm": board.square_m * 1000,
                  "marker_mm": board.marker_m * 1000, "dictionary": board.dictionary}
    record |= {"id": check_id, "frame_id": entry.id, "frame_ids": [e.id for e in used], "frames_requested": n_frames, "board": board_json}
    if note := frames_note(len(used), n_frames, entry.id):
        record["frames_note"] = note
    if done.png:
        save_picture(log, check_id, done.png)
        record["png_url"] = f"api/checks/{check_id}/check.png"
    append_check(log, record)
    return record
