"""Writing a recording, durably, frame by frame (see ``device.formats.recording`` for the layout)."""

from __future__ import annotations

import errno
import json
import math
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame

from device.base import REBUILD_IMAGE, SourceInfo
from device.errors import RecordingError
from device.formats.recording.format import (
    _MANIFEST_INTERVAL_S,
    _SAFE_KEY,
    DISPARITY_SCALE,
    FORMAT,
    FORMAT_VERSION,
    FRAMES,
    MANIFEST,
    RAW_KEYS,
    _append_line,
    _calib_json,
    _encode_npy,
    _encode_png,
    _encode_smooth_png,
    _fsync_dir,
    _info_json,
    _NotJSON,
    _write_file,
    _write_json_atomic,
    encode_confidence,
    encode_disparity,
    jsonable,
)

# writer


def _is_recording(path: Path) -> bool:
    return (path / MANIFEST).exists() or (path / FRAMES).exists()


class RecordingWriter:
    """Writes frames into a recording directory, durably, frame by frame.

    ``with RecordingWriter(out_dir, source.info) as rec: rec.write(frame)``. An existing recording
    is only replaced with ``overwrite=True``; the new one is then written beside it (in
    ``.NAME.partial``) and swapped in on close, so a crash keeps the old one intact. A directory
    that holds anything else is never touched.
    """

    def __init__(self, out_dir: str | Path, info: SourceInfo, *, overwrite: bool = False, keep_raw: bool = False) -> None:
        self.path = Path(out_dir)
        self.info = info
        self.keep_raw = keep_raw
        self._replace = False
        self._count = 0
        self._closed = False
        self._failed: str | None = None
        self._manifest: dict[str, Any] | None = None
        self._last_manifest = 0.0
        self._bytes = 0
        self._made_dirs: set[str] = set()
        self._fd: int | None = None
        self._pool = ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)), thread_name_prefix="png")
        if self.path.exists():
            if not self.path.is_dir():
                raise RecordingError(f"{self.path} is a file, not a directory; choose another --out directory")
            if _is_recording(self.path):
                if not overwrite:
                    raise RecordingError(
                        f"{self.path} already holds a recording; pass overwrite=True (--overwrite) to replace it "
                        "or choose another --out directory"
                    )
                self._replace = True
            elif any(self.path.iterdir()):
                raise RecordingError(
                    f"{self.path} is not empty and is not a recording; choose a new or empty --out directory "
                    "(depthruler never deletes files it did not write)"
                )
        self.root = self.path.with_name(f".{self.path.name}.partial") if self._replace else self.path
        try:
            if self._replace and self.root.exists():
                shutil.rmtree(self.root)  # the leftover of an earlier overwrite that crashed
            self.root.mkdir(parents=True, exist_ok=True)
            self._manifest = {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "created": datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
                "created_unix": time.time(),
                "source": _info_json(info),
                "camera": None,
                "baseline_m": None,
                "doffs": None,
                "disparity_scale": DISPARITY_SCALE,
                "keep_raw": bool(keep_raw),
                "frame_count": 0,
                "complete": False,
            }
            _write_json_atomic(self.root / MANIFEST, self._manifest)
            self._fd = os.open(self.root / FRAMES, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            _fsync_dir(self.root)
        except OSError as exc:
            raise RecordingError(f"cannot create the recording {self.root}: {exc.strerror or exc}; check the path and free space") from exc

    @property
    def frames_written(self) -> int:
        return self._count

    @property
    def bytes_written(self) -> int:
        return self._bytes

    def _dir(self, rel: str) -> Path:
        d = self.root / rel
        if rel not in self._made_dirs:
            d.mkdir(parents=True, exist_ok=True)
            self._made_dirs.add(rel)
        return d

    def _saved(self) -> str:
        return f"the recording {self.root} keeps its {self._count} complete frames (0..{self._count - 1})"

    def write(self, frame: Frame, raw: tuple[np.ndarray, np.ndarray] | None = None) -> int:
        """Store one frame durably; returns its index. ``raw`` = (left, right) stereo images, kept with keep_raw."""
        if self._closed:
            raise RecordingError(f"the recording {self.path} is closed; open a new RecordingWriter to record more")
        if self._failed:
            raise RecordingError(f"an earlier write failed ({self._failed}); {self._saved()}; start a new recording")
        if not isinstance(frame, Frame):
            raise RecordingError(f"RecordingWriter.write takes a measure.Frame, got {type(frame).__name__}")
        if not math.isfinite(frame.timestamp):
            raise RecordingError(f"frame.timestamp={frame.timestamp!r} is not a finite number of seconds; fix the source's clock")
        i = self._count
        name = f"{i:06d}"
        disp_code, dropped = encode_disparity(frame.disparity)
        h, w = frame.disparity.shape
        meta: dict[str, Any] = {}
        meta_dropped: list[str] = []
        arrays: dict[str, np.ndarray] = {}
        for key, value in dict(frame.meta).items():
            if key in RAW_KEYS or key == REBUILD_IMAGE:
                continue
            try:
                meta[str(key)] = jsonable(value)
            except _NotJSON:
                if (
                    isinstance(value, np.ndarray)
                    and value.shape[:2] == (h, w)
                    and value.dtype.kind in "biuf"
                    and isinstance(key, str)
                    and _SAFE_KEY.match(key)
                ):
                    arrays[key] = value
                else:
                    meta_dropped.append(str(key))
        if raw is None and self.keep_raw and all(isinstance(frame.meta.get(k), np.ndarray) for k in RAW_KEYS):
            raw = (frame.meta["raw_left"], frame.meta["raw_right"])

        current = ""
        written: list[Path] = []
        pos: int | None = None
        try:
            jobs: list[tuple[str, str, Any, np.ndarray]] = [
                ("color", f"color/{name}.png", _encode_png, np.ascontiguousarray(frame.image)),
                ("disparity", f"disparity/{name}.png", _encode_smooth_png, disp_code),
            ]
            if frame.confidence is not None:
                jobs.append(("confidence", f"confidence/{name}.png", _encode_smooth_png, encode_confidence(frame.confidence)))
            if self.keep_raw and raw is not None:
                for side, img in zip(("left", "right"), raw):
                    jobs.append((f"raw_{side}", f"raw/{side}/{name}.png", _encode_png, np.ascontiguousarray(img)))
            for key, arr in arrays.items():
                jobs.append((f"meta:{key}", f"extra/{key}/{name}.npy", _encode_npy, arr))
            # PNG encoding dominates the cost of a frame; cv2 releases the GIL, so encode side by side.
            futures = [self._pool.submit(fn, arr) for _, _, fn, arr in jobs]
            payload: list[tuple[str, str, bytes]] = []
            for (kind, rel, _, _), fut in zip(jobs, futures):
                current = rel
                payload.append((kind, rel, fut.result()))
            dirs: set[str] = set()
            for _, rel, data in payload:
                current = rel
                parent = rel.rsplit("/", 1)[0]
                self._dir(parent)
                dirs.add(parent)
                written.append(self.root / rel)
                _write_file(self.root / rel, data)
            for parent in sorted(dirs):
                current = parent + "/"
                _fsync_dir(self.root / parent)
            line: dict[str, Any] = {
                "index": i,
                "timestamp": float(frame.timestamp),
                "files": {kind: rel for kind, rel, _ in payload},
                "meta": meta,
            }
            if meta_dropped:
                line["meta_dropped"] = meta_dropped
            if dropped:
                line["disparity_dropped"] = dropped
            calib = _calib_json(frame)
            if self._manifest["camera"] is not None and calib != {k: self._manifest[k] for k in calib}:
                line["calib"] = calib
            current = FRAMES
            pos = os.lseek(self._fd, 0, os.SEEK_END)
            _append_line(self._fd, (json.dumps(line, allow_nan=False) + "\n").encode())
        except OSError as exc:
            if pos is not None:
                try:
                    os.ftruncate(self._fd, pos)  # drop a partly appended line so later readers see none
                except OSError:
                    pass
            for p in written:
                try:
                    p.unlink(missing_ok=True)
                except OSError:
                    pass
            what = "disk full" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
            self._failed = f"{what} while writing {self.root / current}"
            raise RecordingError(
                f"{self._failed}; frame {i} was not saved and {self._saved()}; "
                + ("free some disk space and record again into a new directory" if exc.errno == errno.ENOSPC else "check the disk and record again")
            ) from exc
        self._count += 1
        self._bytes += sum(len(data) for _, _, data in payload)
        if self._manifest["camera"] is None:
            self._manifest.update(calib)
            self._update_manifest(force=True)
        else:
            self._update_manifest()
        return i

    def _update_manifest(self, force: bool = False, complete: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last_manifest < _MANIFEST_INTERVAL_S:
            return
        self._manifest["frame_count"] = self._count
        self._manifest["complete"] = complete
        try:
            _write_json_atomic(self.root / MANIFEST, self._manifest)
        except OSError as exc:
            self._failed = f"{exc.strerror or exc} while writing {self.root / MANIFEST}"
            raise RecordingError(f"{self._failed}; {self._saved()}; free some disk space and record again") from exc
        self._last_manifest = now

    def close(self) -> None:
        """Finish the manifest and, for an overwrite, swap the new recording in place of the old one."""
        if self._closed:
            return
        self._closed = True
        failed_before = self._failed is not None
        try:
            self._update_manifest(force=True, complete=not failed_before)
        except RecordingError:
            if not failed_before:  # after a failed write the disk may still be full; that is already reported
                raise
        finally:
            self._pool.shutdown(wait=True)
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
        if self._replace:
            old = self.path.with_name(f".{self.path.name}.old")
            if old.exists():
                shutil.rmtree(old)
            os.replace(self.path, old)
            os.replace(self.root, self.path)
            _fsync_dir(self.path.parent)
            shutil.rmtree(old)
            self.root = self.path

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
