"""A check as one record of the checks log (``<db stem>-checks.jsonl``, :mod:`history.checks`).

The record holds the time (UTC, ISO 8601), the source spec, the device's kind and serial, the
calibration file the spec names and its SHA-256, the calibration the frames carried and its SHA-256,
and the report (status, figures, findings); NaN and infinities become null (strict JSON). Checks of
the same device kind, serial and frame calibration are the earlier checks a trend is read from.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from device import SourceInfo
from history.checks import calibration_of, camera_of, read_checks
from measure import Frame


def finite(x: Any) -> Any:
    """``x`` with every NaN and infinity (in nested dicts and lists) replaced by None."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite(v) for v in x]
    return x


def check_record(source: str, info: SourceInfo, frame: Frame, report: dict, when: datetime | None = None) -> dict:
    """The checks-log record of ``report`` (:func:`check.run.report`) made on ``frame`` of ``source``."""
    calib, calib_hash = calibration_of(source)
    camera, camera_hash = camera_of(frame)
    return finite({
        "time": (when or datetime.now(timezone.utc)).isoformat(timespec="seconds"),
        "source": source,
        "kind": info.kind,
        "serial": info.serial,
        "calibration": calib,
        "calibration_sha256": calib_hash,
        "camera": camera,
        "camera_sha256": camera_hash,
        **report,
    })  # fmt: skip


def earlier_checks(path: str | Path, info: SourceInfo, frame: Frame) -> Sequence[dict]:
    """The records in the checks log ``path`` of the same device (kind, serial) and frame calibration, newest first."""
    camera_hash = camera_of(frame)[1]
    return [r for r in read_checks(path, serial=info.serial) if r.get("camera_sha256") == camera_hash and r.get("kind") == info.kind]
