"""What one check measured: every pair on every frame, the board in each frame, and the misses."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from device.calibration.board import BoardSpec, Detection

from check.pairs import PairResult
from check.target import BoardView


@dataclass(frozen=True)
class CheckResult:
    """Everything one check measured: per pair, per frame, and the frames that showed no board."""

    board: BoardSpec
    pairs: tuple[PairResult, ...]
    views: tuple[BoardView, ...]
    missed_frames: tuple[int, ...] = ()
    detections: tuple[Detection, ...] = field(default=(), repr=False)  # per view, for drawing
    fx_baseline: float = math.nan  # fx * B (px m) of the first frame with the board
    legacy_found: bool = False  # the board was described in today's pattern but found in the legacy one
    source_kind: str | None = None  # that frame's meta["source"] ("oak", "v4l2", "sim", ...): what advice fits
