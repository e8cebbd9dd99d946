"""The bag source's configuration: the bag's path and its spec options (units: metres, milliseconds)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from device.errors import SourceError

@dataclass(frozen=True)
class BagOptions:
    """Spec options: explicit topics, ``baseline`` (m), ``depth_unit`` (m per 16-bit step), ``skew_ms``,
    ``registered`` (treat depth as registered to colour), ``loop``, ``realtime``, ``speed``, ``start``."""

    topics: tuple[tuple[str, str], ...] = ()
    baseline_m: float | None = None
    depth_unit_m: float | None = None
    skew_ms: float | None = None
    registered: bool = False
    loop: bool = False
    realtime: bool = False
    speed: float = 1.0
    start: int = 0

    def __post_init__(self) -> None:
        for name in ("baseline_m", "depth_unit_m", "skew_ms"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise SourceError(f"bag option {name.removesuffix('_m').removesuffix('_ms')}={v} must be a positive number")
        if not (self.speed > 0 and math.isfinite(self.speed)):
            raise SourceError(f"speed={self.speed} must be a positive number (1 = as recorded)")
        if self.start < 0:
            raise SourceError(f"start={self.start} must be a frame index >= 0")


@dataclass(frozen=True)
class BagConfig:
    """A bag source: the bag (ROS 1 .bag, ROS 2 folder or .mcap) and its options."""

    path: Path
    options: BagOptions = BagOptions()
