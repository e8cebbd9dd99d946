"""The history of accuracy checks (`depthruler check`): one JSON line per check, next to the service's database.

A camera's accuracy is followed over weeks, so each line keeps what identifies the chain that was
checked (source spec, device serial, the calibration file and its SHA-256, and the calibration the
frames carried with its own SHA-256, which also identifies on-board calibrations) with the time and
the figures. The file is ``<db stem>-checks.jsonl`` beside the service database (``depthruler.db`` ->
``depthruler-checks.jsonl``), where ``GET /api/checks`` reads it. Lines are appended whole and
fsync'd; a reader skips a truncated or corrupt line (a crash mid-write) instead of failing.
The check (``depthruler check``) writes it and the service reads it; both import this package.
A check run from the page also keeps its picture, ``<db stem>-checks/<id>.png``, named by the record's ``id``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from measure import Frame

from device.base import SourceSpec
from device.errors import SourceError


class CheckHistoryError(SourceError):
    """The checks file cannot be written; the message names it."""


def checks_path(db_path: str | Path) -> Path:
    """The checks file that belongs to service database ``db_path``."""
    db = Path(db_path)
    return db.with_name(db.stem + "-checks.jsonl")


def calibration_of(spec: str) -> tuple[str | None, str | None]:
    """The calibration file(s) a source spec names (``calib=``) and their SHA-256 (files joined in order);
    (None, None) when the spec names none (a simulator, or a device with its calibration on board)."""
    params = SourceSpec.parse(spec).params
    calib = params.get("calib")
    if not calib:
        return None, None
    digest = hashlib.sha256()
    for part in calib.split(","):
        try:
            digest.update(Path(part).read_bytes())
        except OSError:
            return calib, None
    return calib, digest.hexdigest()


def camera_of(frame: Frame) -> tuple[dict[str, float], str]:
    """The calibration a frame was measured with (intrinsics, size, baseline, doffs) and its SHA-256.

    This identifies the calibration in use whatever its origin: a file named by the spec, a
    device's on-board calibration (an OAK's EEPROM, which no spec names), or a simulator's. A
    recalibrated device gives another hash, so its checks are not compared with the old ones.
    Values are rounded to 1e-6 (px, m) so that a float printed and parsed again hashes the same.
    """
    cam = frame.camera
    values = {
        "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width, "height": cam.height,
        "baseline_m": frame.baseline_m, "doffs": frame.doffs,
    }
    values = {k: round(float(v), 6) for k, v in values.items()}
    text = json.dumps(values, sort_keys=True, separators=(",", ":"))
    return values, hashlib.sha256(text.encode("ascii")).hexdigest()


def append_check(path: str | Path, record: dict[str, Any]) -> Path:
    """Append one check record (JSON-ready) as a line, durable when this returns."""
    path = Path(path)
    line = json.dumps(record, allow_nan=False, separators=(",", ":")) + "\n"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "a+b") as fh:
            fh.seek(0, os.SEEK_END)
            if fh.tell() > 0:
                fh.seek(-1, os.SEEK_END)
                if fh.read(1) != b"\n":
                    line = "\n" + line  # a line cut by a crash stays alone; this record starts its own
            fh.write(line.encode("utf-8"))
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        raise CheckHistoryError(f"cannot append to the checks file {path}: {exc}; pass --db with a writable path") from exc
    return path


def read_checks(path: str | Path, *, serial: str | None = None, limit: int | None = None) -> list[dict[str, Any]]:
    """The checks in ``path``, newest first, optionally of one device ``serial`` and at most ``limit``."""
    path = Path(path)
    if not path.is_file():
        return []
    out = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line cut short by a crash
            if isinstance(record, dict) and (serial is None or record.get("serial") == serial):
                out.append(record)
    out.reverse()
    return out[:limit] if limit is not None else out


def pictures_dir(path: str | Path) -> Path:
    """The folder of check pictures that belongs to checks file ``path`` (``x-checks.jsonl`` -> ``x-checks/``)."""
    path = Path(path)
    return path.with_name(path.stem)


def picture_path(path: str | Path, check_id: str) -> Path:
    """The picture of check ``check_id`` (hex digits, as :func:`save_picture` names them) beside checks file ``path``;
    ValueError for any other id, so a path never leaves the folder."""
    if not (check_id and len(check_id) <= 64 and all(c in "0123456789abcdef" for c in check_id)):
        raise ValueError(f"{check_id!r} is not a check id (lowercase hex digits)")
    return pictures_dir(path) / f"{check_id}.png"


def save_picture(path: str | Path, check_id: str, png: bytes) -> Path:
    """Write check ``check_id``'s picture beside checks file ``path`` (fsync'd), before its record is appended."""
    out = picture_path(path, check_id)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(".tmp")
        with open(tmp, "wb") as fh:
            fh.write(png)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, out)
    except OSError as exc:
        raise CheckHistoryError(f"cannot write the check picture {out}: {exc}; free space or fix the folder's permissions") from exc
    return out
