"""Recording and replay of frames in depthruler's directory format (ARCHITECTURE.md "Recording format").

Layout of one recording directory::

    manifest.json          format, format_version, source info, camera, baseline_m, doffs, created,
                           frame_count (a hint only: frames.jsonl is the truth), complete
    frames.jsonl           one JSON line per frame, append-only: index, timestamp, files, meta
    color/000000.png       BGR uint8, lossless
    disparity/000000.png   uint16 = round(d * 64), 0 = invalid (NaN); 1/64 px steps, d < 1024 px
    confidence/000000.png  optional, uint8 = round(c * 255)
    raw/left/000000.png    optional (keep_raw): the rectified stereo pair, so SGBM can be re-run
    raw/right/000000.png
    extra/KEY/000000.npy   optional: image-sized arrays found in frame.meta (e.g. Middlebury's
                           "gt_disparity"), stored losslessly with numpy

Durability: per frame, every image file is written and fsync'd (and its directory), then the
frames.jsonl line is appended and fsync'd. A frame exists only once its line is complete, so a
crash or a pulled cable loses at most the frame in flight; the reader skips a truncated last line
and reports it in ``Recording.problems``. The manifest is replaced atomically (temp file, fsync,
``os.replace``) after the first frame, then at most once a second and on close.

Disparity that cannot be stored: a disparity of 1024 px or more raises :class:`RecordingError`
(nothing of that frame is written); negative disparity and disparity below 1/128 px (it would
round to the invalid code 0) are stored as invalid and counted in the frame's line as
``disparity_dropped``. Meta values are kept when JSON can hold them; a dataclass (e.g. the
simulator's ``Truth``) is kept as a JSON summary of its small fields (its ``depth_m`` image is
dropped); other values are dropped and their keys listed in ``meta_dropped``.

Replay: ``replay:DIR?loop=1&realtime=1&speed=1`` yields the frames again (colour bit-identical,
disparity within 1/128 px). At the end of a recording without ``loop`` ``read`` raises
:class:`EndOfRecording`, a :class:`SourceEnded`: the stream has ended.
"""

from __future__ import annotations

import dataclasses
import errno
import io
import json
import math
import os
import re
import shutil
import time
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, PinholeCamera

from .base import SourceBase, SourceInfo, SourceSpec
from .errors import RecordingError, SourceEnded, SourceError, SourceNotFound, SourceTimeout

FORMAT = "depthruler-recording"
FORMAT_VERSION = 1
DISPARITY_SCALE = 64
MAX_DISPARITY_CODE = 65535
MANIFEST = "manifest.json"
FRAMES = "frames.jsonl"
RAW_KEYS = ("raw_left", "raw_right")
_MANIFEST_INTERVAL_S = 1.0
_PNG_COMPRESSION = 1  # zlib level 1: lossless like any level, ~2x faster than OpenCV's default 3 for ~3 % more bytes
_SAFE_KEY = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_SMALL_ARRAY = 64  # arrays up to this many elements go into the JSON meta as lists


class EndOfRecording(SourceEnded):
    """A replay reached the last frame (and was not asked to loop)."""


class RecordingNotFound(RecordingError, SourceNotFound):
    """The path given is not there or holds no recording."""


# ---------------------------------------------------------------------------------------------
# encoding of the arrays


def encode_disparity(disparity: np.ndarray) -> tuple[np.ndarray, int]:
    """Disparity (float px, NaN invalid) -> (uint16 code = round(d * 64), 0 = invalid; pixels dropped).

    Raises RecordingError when a disparity of 1024 px or more cannot be stored. Negative values and
    values below 1/128 px (which round to the invalid code) become invalid and are counted.
    """
    d = np.asarray(disparity, dtype=np.float32)
    finite = np.isfinite(d)
    scaled = np.where(finite, d, 0.0).astype(np.float64) * DISPARITY_SCALE
    code = np.rint(scaled)
    too_big = code > MAX_DISPARITY_CODE
    if too_big.any():
        raise RecordingError(
            f"{int(too_big.sum())} pixels have disparity >= {MAX_DISPARITY_CODE / DISPARITY_SCALE:.2f} px "
            f"(largest {float(d[too_big].max()):.1f} px), beyond what the 16-bit 1/64-px format stores; "
            "record at a lower resolution or a larger working distance"
        )
    keep = finite & (code >= 1)
    out = np.zeros(d.shape, dtype=np.uint16)
    out[keep] = code[keep].astype(np.uint16)
    dropped = int(np.count_nonzero(finite & ~keep) + np.count_nonzero(np.isinf(d)))
    return out, dropped


def decode_disparity(code: np.ndarray) -> np.ndarray:
    """uint16 code -> float32 disparity in pixels, NaN where the code is 0."""
    d = code.astype(np.float32) / np.float32(DISPARITY_SCALE)
    d[code == 0] = np.nan
    return d


def encode_confidence(confidence: np.ndarray) -> np.ndarray:
    c = np.nan_to_num(np.asarray(confidence, dtype=np.float32), nan=0.0)
    return np.rint(np.clip(c, 0.0, 1.0) * 255.0).astype(np.uint8)


def decode_confidence(code: np.ndarray) -> np.ndarray:
    return code.astype(np.float32) / np.float32(255.0)


def _encode_png(image: np.ndarray, row_filter: str = "sub") -> bytes:
    """Lossless PNG. A fixed row filter (instead of libpng's adaptive choice) roughly halves the
    encoding time at 720p for ~5 % more bytes: "sub" suits photos, "up" smooth disparity maps."""
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, _PNG_COMPRESSION]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.10
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP if row_filter == "up" else cv2.IMWRITE_PNG_FILTER_SUB]
    ok, buf = cv2.imencode(".png", image, params)
    if not ok:
        raise RecordingError(f"OpenCV could not PNG-encode a {image.shape} {image.dtype} image")
    return buf.tobytes()


def _encode_smooth_png(image: np.ndarray) -> bytes:
    return _encode_png(image, "up")


def _encode_npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------
# durable file operations


def _write_file(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _append_line(fd: int, data: bytes) -> None:
    """Append all of ``data`` to the open file descriptor and fsync it (os.write may write partially)."""
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]
    os.fsync(fd)


def _write_json_atomic(path: Path, obj: Mapping[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        _write_file(tmp, (json.dumps(obj, indent=2, allow_nan=False) + "\n").encode())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


# ---------------------------------------------------------------------------------------------
# meta to JSON


class _NotJSON(TypeError):
    """The value has no faithful JSON form."""


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON (non-finite floats become None, small arrays lists), or raise _NotJSON."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, np.bool_):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, Mapping):
        if not all(isinstance(k, str) for k in value):
            raise _NotJSON("a mapping with non-string keys")
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray) and value.size <= _SMALL_ARRAY and value.dtype.kind in "biuf":
        return jsonable(value.tolist())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _dataclass_summary(value)
    raise _NotJSON(f"{type(value).__name__} has no JSON form")


def _dataclass_summary(obj: Any) -> dict[str, Any]:
    """The JSON-able fields of a dataclass (e.g. sim.Truth without its depth image), tagged with its type."""
    out: dict[str, Any] = {"_type": type(obj).__name__}
    for f in dataclasses.fields(obj):
        try:
            out[f.name] = jsonable(getattr(obj, f.name))
        except _NotJSON:
            continue
    return out


def _camera_json(camera: PinholeCamera) -> dict[str, Any]:
    return {k: jsonable(getattr(camera, k)) for k in ("fx", "fy", "cx", "cy", "width", "height")}


def _calib_json(frame: Frame) -> dict[str, Any]:
    return {"camera": _camera_json(frame.camera), "baseline_m": float(frame.baseline_m), "doffs": float(frame.doffs)}


def _info_json(info: SourceInfo) -> dict[str, Any]:
    out = {k: jsonable(getattr(info, k)) for k in ("kind", "name", "serial", "width", "height", "fps", "state")}
    extra = {}
    for k, v in dict(info.extra).items():
        try:
            extra[str(k)] = jsonable(v)
        except _NotJSON:
            continue
    out["extra"] = extra
    return out


# ---------------------------------------------------------------------------------------------
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
            if key in RAW_KEYS:
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


# ---------------------------------------------------------------------------------------------
# reader


_REQUIRED: Any = object()


class _Fields:
    """Typed access to one JSON object of a recording: a missing or type-wrong value is a
    RecordingError naming the file, the line (for frames.jsonl) and the field, never a TypeError."""

    def __init__(self, obj: Any, file: Path, line: int | None = None, prefix: str = "") -> None:
        self.file, self.line, self.prefix = file, line, prefix
        if not isinstance(obj, dict):
            raise self.error(prefix.rstrip(".") or "(the whole entry)", "must be a JSON object", obj)
        self.obj: dict[str, Any] = obj

    def error(self, name: str, what: str, value: Any = _REQUIRED) -> RecordingError:
        where = f"{self.file} line {self.line}" if self.line is not None else str(self.file)
        got = "" if value is _REQUIRED else f" (got {json.dumps(value)[:60] if _dumpable(value) else type(value).__name__})"
        return RecordingError(f"{where}: field {self.prefix}{name} {what}{got}; the file is damaged")

    def _get(self, key: str, default: Any) -> Any:
        if key not in self.obj:
            if default is _REQUIRED:
                raise self.error(key, "is missing")
            return default
        return self.obj[key]

    def number(self, key: str, default: Any = _REQUIRED, *, nullable: bool = False) -> Any:
        v = self._get(key, default)
        if (v is None and nullable) or (v is default and key not in self.obj):
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.error(key, "must be a finite number", v)
        return float(v)

    def integer(self, key: str, default: Any = _REQUIRED, *, minimum: int | None = None, nullable: bool = False) -> Any:
        v = self._get(key, default)
        if (v is None and nullable) or (v is default and key not in self.obj):
            return v
        if isinstance(v, bool) or not isinstance(v, int) or (minimum is not None and v < minimum):
            raise self.error(key, "must be an integer" + (f" >= {minimum}" if minimum is not None else ""), v)
        return v

    def string(self, key: str, default: Any = _REQUIRED) -> Any:
        v = self._get(key, default)
        if v is default and key not in self.obj:
            return v
        if not isinstance(v, str):
            raise self.error(key, "must be a string", v)
        return v

    def fields(self, key: str, default: Any = _REQUIRED) -> _Fields | None:
        v = self._get(key, default)
        if v is None and key not in self.obj:
            return None
        return _Fields(v, self.file, self.line, f"{self.prefix}{key}.")

    def camera(self, key: str) -> PinholeCamera:
        c = self.fields(key)
        assert c is not None
        values = {k: c.number(k) for k in ("fx", "fy", "cx", "cy")}
        size = {k: c.integer(k, minimum=1) for k in ("width", "height")}
        try:
            return PinholeCamera(**values, **size)
        except (TypeError, ValueError) as exc:
            raise self.error(key, f"is not a valid camera ({exc})") from None

    def rel_path(self, key: str, rel: Any) -> str:
        """A file named by the recording: relative, inside it, written with '/' (as the writer does)."""
        parts = rel.split("/") if isinstance(rel, str) else []
        if (
            not isinstance(rel, str)
            or not rel
            or rel.startswith("/")
            or "\\" in rel
            or "\0" in rel
            or any(p in ("", ".", "..") for p in parts)
        ):
            raise self.error(key, "must be a relative path inside the recording (like color/000000.png)", rel)
        return rel


def _dumpable(value: Any) -> bool:
    try:
        json.dumps(value)
        return True
    except (TypeError, ValueError):
        return False


def _inside(root: Path, rel: str, what: str) -> Path:
    """``root / rel``, refused when it leads out of the recording (a symlink placed inside it)."""
    p = root / rel
    try:
        real = p.resolve()
    except (OSError, RuntimeError) as exc:
        raise RecordingError(f"{p} ({what}) cannot be resolved ({exc})") from exc
    if not real.is_relative_to(root.resolve()):
        raise RecordingError(f"{p} ({what}) leads to {real}, outside the recording; this frame cannot be replayed")
    return p


@dataclass(frozen=True)
class FrameEntry:
    """One complete line of frames.jsonl."""

    index: int
    timestamp: float
    files: Mapping[str, str]
    meta: Mapping[str, Any]
    line: int  # 1-based line number in frames.jsonl
    calib: Mapping[str, Any] | None = None
    disparity_dropped: int = 0
    meta_dropped: tuple[str, ...] = ()


def _read_manifest(path: Path) -> dict[str, Any]:
    mpath = path / MANIFEST
    if not mpath.is_file():
        if (path / FRAMES).is_file():
            raise RecordingError(
                f"{mpath} is missing, so the camera and baseline of this recording are unknown; "
                "restore manifest.json from a backup or record again"
            )
        raise RecordingNotFound(f"{path} is not a depthruler recording (no {MANIFEST}); give a directory written by `depthruler record`")
    try:
        manifest = json.loads(mpath.read_text())
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{mpath} cannot be read as JSON ({exc}); restore it from a backup or record again") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise RecordingError(f"{mpath} is not a depthruler recording manifest (format is not {FORMAT!r})")
    version = manifest.get("format_version")
    if not isinstance(version, int) or version < 1:
        raise RecordingError(f"{mpath} has an invalid format_version {version!r}; the manifest is damaged")
    if version > FORMAT_VERSION:
        raise RecordingError(
            f"{mpath} has format_version {version}, newer than the {FORMAT_VERSION} this depthruler reads; "
            "upgrade depthruler (pip install -U depthruler) to read it"
        )
    return manifest


@dataclass(frozen=True)
class _ManifestFacts:
    camera: PinholeCamera | None
    baseline_m: float | None
    doffs: float
    source: SourceInfo


def _manifest_facts(manifest: dict[str, Any], mpath: Path) -> _ManifestFacts:
    """The typed facts of a manifest; any type-wrong value is a RecordingError naming the field."""
    m = _Fields(manifest, mpath)
    camera = m.camera("camera") if manifest.get("camera") is not None else None
    baseline = m.number("baseline_m", None, nullable=True)
    doffs = m.number("doffs", None, nullable=True)
    src = m.fields("source", None) or _Fields({}, mpath, prefix="source.")
    extra = src.fields("extra", None)
    info = SourceInfo(
        kind=src.string("kind", ""),
        name=src.string("name", ""),
        serial=src.string("serial", ""),
        width=src.integer("width", 0, minimum=0, nullable=True) or 0,
        height=src.integer("height", 0, minimum=0, nullable=True) or 0,
        fps=src.number("fps", 0.0, nullable=True) or 0.0,
        state=src.string("state", ""),
        extra=dict(extra.obj) if extra else {},
    )
    return _ManifestFacts(camera=camera, baseline_m=baseline, doffs=doffs or 0.0, source=info)


def _entry(obj: Any, fpath: Path, n: int) -> FrameEntry:
    """One frames.jsonl line, every field type-checked (RecordingError naming file, line, field)."""
    f = _Fields(obj, fpath, n)
    files_f = f.fields("files")
    assert files_f is not None
    files = {str(kind): files_f.rel_path(str(kind), rel) for kind, rel in files_f.obj.items()}
    for need in ("color", "disparity"):
        if need not in files:
            raise files_f.error(need, "is missing")
    calib = None
    if obj.get("calib") is not None:
        c = f.fields("calib")
        assert c is not None
        camera = c.camera("camera")
        calib = {"camera": {k: getattr(camera, k) for k in ("fx", "fy", "cx", "cy", "width", "height")},
                 "baseline_m": c.number("baseline_m"), "doffs": c.number("doffs")}  # fmt: skip
    meta = f.fields("meta", {})
    dropped = obj.get("meta_dropped", [])
    if not isinstance(dropped, list) or not all(isinstance(k, str) for k in dropped):
        raise f.error("meta_dropped", "must be a list of strings", dropped)
    return FrameEntry(
        index=f.integer("index", minimum=0),
        timestamp=f.number("timestamp"),
        files=files,
        meta=dict(meta.obj) if meta else {},
        line=n,
        calib=calib,
        disparity_dropped=f.integer("disparity_dropped", 0, minimum=0),
        meta_dropped=tuple(dropped),
    )


def _read_index(path: Path) -> tuple[list[FrameEntry], list[str]]:
    fpath = path / FRAMES
    if not fpath.is_file():
        raise RecordingError(f"{fpath} is missing, so no frame of this recording can be found; record again")
    data = fpath.read_bytes()
    lines = data.split(b"\n")
    tail = lines.pop()  # after the last newline: empty, or a line cut short by a crash
    entries: list[FrameEntry] = []
    problems: list[str] = []
    for n, raw in enumerate(lines, start=1):
        if not raw.strip():
            continue
        try:
            obj = json.loads(raw)
        except ValueError as exc:
            problems.append(f"{fpath} line {n} is corrupt (not JSON: {exc}); that frame was skipped")
            continue
        try:
            entries.append(_entry(obj, fpath, n))
        except RecordingError as exc:
            problems.append(f"{exc}; that frame was skipped")
    if tail.strip():
        problems.append(
            f"{fpath} line {len(lines) + 1} is incomplete (the recording stopped mid-frame); it was skipped, "
            f"{len(entries)} complete frames remain"
        )
    return entries, problems


def _read_image(root: Path, rel: str, what: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    import cv2

    p = _inside(root, rel, what)
    if not p.is_file():
        raise RecordingError(f"{p} ({what}) is missing; this frame cannot be replayed, the others can (skip it or record again)")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RecordingError(f"{p} ({what}) is corrupt and cannot be decoded; this frame cannot be replayed, the others can")
    if img.dtype != dtype or (shape and img.shape != shape):
        raise RecordingError(
            f"{p} ({what}) is {img.shape} {img.dtype}, expected {shape} {np.dtype(dtype).name}; the file was replaced or damaged"
        )
    return img


@dataclass(frozen=True)
class Recording:
    """A recording opened for reading: manifest, complete frame entries, and any problems found."""

    path: Path
    manifest: Mapping[str, Any]
    camera: PinholeCamera | None
    baseline_m: float | None
    doffs: float
    source: SourceInfo
    entries: tuple[FrameEntry, ...]
    problems: tuple[str, ...] = field(default=())

    def __len__(self) -> int:
        return len(self.entries)

    @property
    def timestamps(self) -> np.ndarray:
        return np.array([e.timestamp for e in self.entries], dtype=np.float64)

    def calibration(self, i: int) -> tuple[PinholeCamera, float, float]:
        """Camera, baseline (m) and doffs (px) of frame ``i``."""
        calib = self.entries[i].calib
        if calib:
            return PinholeCamera(**calib["camera"]), float(calib["baseline_m"]), float(calib["doffs"])
        if self.camera is None or self.baseline_m is None:
            raise RecordingError(f"{self.path / MANIFEST} has no camera; the manifest is damaged")
        return self.camera, self.baseline_m, self.doffs

    def frame(self, i: int) -> Frame:
        """Frame ``i`` (0-based position among the complete frames) as it was recorded."""
        if not 0 <= i < len(self.entries):
            raise IndexError(f"frame {i} is out of range: {self.path} has {len(self.entries)} frames")
        e = self.entries[i]
        camera, baseline_m, doffs = self.calibration(i)
        hw = (camera.height, camera.width)
        image = _read_image(self.path, e.files["color"], "colour", (*hw, 3), np.uint8)
        disparity = decode_disparity(_read_image(self.path, e.files["disparity"], "disparity", hw, np.uint16))
        confidence = None
        if "confidence" in e.files:
            confidence = decode_confidence(_read_image(self.path, e.files["confidence"], "confidence", hw, np.uint8))
        meta = dict(e.meta)
        for kind, rel in e.files.items():
            if kind.startswith("meta:"):
                p = _inside(self.path, rel, f"meta array {kind[5:]!r}")
                try:
                    meta[kind[5:]] = np.load(p, allow_pickle=False)
                except (OSError, ValueError) as exc:
                    raise RecordingError(f"{p} (meta array {kind[5:]!r}) cannot be read ({exc}); this frame cannot be replayed, the others can") from exc
        return Frame(
            image=image,
            disparity=disparity,
            camera=camera,
            baseline_m=baseline_m,
            doffs=doffs,
            confidence=confidence,
            timestamp=e.timestamp,
            meta=meta,
        )

    def raw(self, i: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The raw (left, right) stereo images of frame ``i`` if they were kept, else None."""
        e = self.entries[i]
        if "raw_left" not in e.files or "raw_right" not in e.files:
            return None
        left, right = (self._raw_image(e.files[k], k) for k in RAW_KEYS)
        return left, right

    def _raw_image(self, rel: str, what: str) -> np.ndarray:
        import cv2

        p = _inside(self.path, rel, what)
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED) if p.is_file() else None
        if img is None:
            raise RecordingError(f"{p} ({what}) is missing or corrupt; this frame's raw pair cannot be replayed, the others can")
        return img

    def frames(self) -> Iterator[Frame]:
        for i in range(len(self.entries)):
            yield self.frame(i)

    def size_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.path.rglob("*") if p.is_file())


def open_recording(path: str | Path, *, strict: bool = False) -> Recording:
    """Open a recording directory; raises RecordingError (naming the file) when it cannot be read.

    Damage that costs no complete frame (a truncated last line of frames.jsonl, a corrupt line) is
    skipped and listed in ``Recording.problems``; with ``strict=True`` it raises RecordingError instead.
    """
    path = Path(path)
    if not path.exists():
        raise RecordingNotFound(f"{path} does not exist; give the directory that `depthruler record --out` wrote")
    if not path.is_dir():
        raise RecordingNotFound(f"{path} is a file; a recording is a directory with {MANIFEST} and {FRAMES}")
    manifest = _read_manifest(path)
    entries, problems = _read_index(path)
    if strict and problems:
        raise RecordingError("; ".join(problems) + "; open without strict to use the complete frames")
    facts = _manifest_facts(manifest, path / MANIFEST)
    if entries and facts.camera is None:
        raise RecordingError(f"{path / MANIFEST} has no camera although frames.jsonl lists frames; the manifest is damaged")
    return Recording(
        path=path,
        manifest=manifest,
        camera=facts.camera,
        baseline_m=facts.baseline_m,
        doffs=facts.doffs,
        source=facts.source,
        entries=tuple(entries),
        problems=tuple(problems),
    )


def summarize(rec: Recording) -> dict[str, Any]:
    """What `depthruler replay DIR` shows: manifest facts, timing, problems and valid-disparity shares."""
    shares: list[float] = []
    unreadable: list[str] = []
    for i in range(len(rec)):
        try:
            f = rec.frame(i)
        except RecordingError as exc:
            unreadable.append(str(exc))
            continue
        shares.append(float(np.isfinite(f.disparity).mean()))
    ts = rec.timestamps
    duration = float(ts[-1] - ts[0]) if len(ts) > 1 else 0.0
    share = np.array(shares) if shares else np.array([np.nan])
    return {
        "path": str(rec.path),
        "format_version": rec.manifest.get("format_version"),
        "created": rec.manifest.get("created"),
        "complete": bool(rec.manifest.get("complete")),
        "source": dataclasses.asdict(rec.source),
        "camera": _camera_json(rec.camera) if rec.camera else None,
        "baseline_m": rec.baseline_m,
        "doffs": rec.doffs,
        "frames": len(rec),
        "manifest_frame_count": rec.manifest.get("frame_count"),
        "duration_s": duration,
        "fps": (len(ts) - 1) / duration if duration > 0 else None,
        "size_bytes": rec.size_bytes(),
        "has_confidence": any("confidence" in e.files for e in rec.entries),
        "has_raw": any("raw_left" in e.files for e in rec.entries),
        "valid_disparity": {
            "min": jsonable(float(np.nanmin(share))) if shares else None,
            "median": jsonable(float(np.nanmedian(share))) if shares else None,
            "max": jsonable(float(np.nanmax(share))) if shares else None,
            "per_frame": [round(s, 4) for s in shares],
        },
        "problems": list(rec.problems) + unreadable,
        "unreadable_frames": len(unreadable),
    }


# ---------------------------------------------------------------------------------------------
# replay as a Source


@dataclass(frozen=True)
class ReplayConfig:
    """``path``: the recording; ``loop``: start again at the end; ``realtime``: pace frames by their
    recorded timestamps (divided by ``speed``) instead of as fast as possible; ``start``: first frame."""

    path: Path
    loop: bool = False
    realtime: bool = False
    speed: float = 1.0
    start: int = 0

    def __post_init__(self) -> None:
        if not (self.speed > 0 and math.isfinite(self.speed)):
            raise SourceError(f"speed={self.speed} must be a positive number (1 = as recorded)")
        if self.start < 0:
            raise SourceError(f"start={self.start} must be a frame index >= 0")


class ReplaySource(SourceBase):
    """A recording played back as a Source: the frames as recorded, in order."""

    def __init__(self, config: ReplayConfig | str | Path) -> None:
        self.config = config if isinstance(config, ReplayConfig) else ReplayConfig(path=Path(config))
        self.info = SourceInfo(kind="replay", name=Path(self.config.path).name)
        self.recording: Recording | None = None
        self._pos = 0
        self._offsets = np.zeros(0)
        self._cycle_start: float | None = None
        self.warnings: list[str] = []  # frames skipped because they could not be read

    def open(self) -> None:
        rec = open_recording(self.config.path)
        if len(rec) == 0:
            raise RecordingError(f"{rec.path / FRAMES} lists no complete frame; there is nothing to replay")
        if self.config.start >= len(rec):
            raise SourceError(f"start={self.config.start} is past the end: {rec.path} has {len(rec)} frames")
        ts = rec.timestamps
        if len(ts) > 1 and np.all(np.diff(ts) >= 0) and ts[-1] > ts[0]:
            self._offsets = ts - ts[0]
        elif rec.source.fps > 0:
            self._offsets = np.arange(len(rec)) / rec.source.fps
        else:
            self._offsets = np.zeros(len(rec))  # no timing recorded: realtime has nothing to follow
        self.recording = rec
        self._pos = self.config.start
        self._cycle_start = None
        cam = rec.camera
        self.info = SourceInfo(
            kind="replay",
            name=rec.source.name or rec.path.name,
            serial=rec.source.serial,
            width=cam.width if cam else 0,
            height=cam.height if cam else 0,
            fps=rec.source.fps,
            extra={"path": str(rec.path), "frames": len(rec), "recorded_kind": rec.source.kind},
        )
        super().open()

    def read(self, timeout_s: float = 1.0) -> Frame:
        rec = self.recording
        if rec is None or not self.is_open:
            raise SourceError("the replay source is not open; call open() or use it in a with block")
        if self._pos >= len(rec):
            if not self.config.loop:
                raise EndOfRecording(f"the replay of {rec.path} reached its end after {len(rec)} frames; use replay:DIR?loop=1 to repeat it")
            self._pos = 0
            self._cycle_start = None
        i = self._pos
        if self.config.realtime:
            now = time.monotonic()
            if self._cycle_start is None:
                self._cycle_start = now - self._offsets[i] / self.config.speed
            wait = self._cycle_start + self._offsets[i] / self.config.speed - now
            if wait > timeout_s:
                time.sleep(max(timeout_s, 0.0))
                raise SourceTimeout(f"the next replayed frame is due in {wait:.2f} s, after the {timeout_s} s timeout")
            if wait > 0:
                time.sleep(wait)
        self._pos += 1
        try:
            frame = rec.frame(i)
        except RecordingError as exc:
            # one damaged frame must not end (or, reopened, restart) the replay: skip it, say so
            self.warnings.append(f"{exc}; frame {i} skipped")
            if len(self.warnings) >= len(rec) and self.config.loop:
                raise RecordingError(f"no frame of {rec.path} can be read ({exc})") from exc
            return self.read(timeout_s)
        meta = dict(frame.meta)
        meta["replay"] = {"path": str(rec.path), "index": i}
        return dataclasses.replace(frame, meta=meta)

    def close(self) -> None:
        self.recording = None
        super().close()


_REPLAY_PARAMS = ("loop", "realtime", "speed", "start")


def from_spec(spec: SourceSpec) -> ReplaySource:
    """``replay:DIR?loop=1&realtime=1&speed=2&start=10`` -> an unopened ReplaySource."""
    if not spec.target:
        raise RecordingNotFound("replay needs a recording directory: replay:path/to/recording")
    spec.check_keys(_REPLAY_PARAMS)
    try:
        speed = float(spec.params.get("speed", "1"))
        start = int(spec.params.get("start", "0"))
    except ValueError as exc:
        raise SourceError(f"replay options speed/start must be numbers: {exc}") from exc
    return ReplaySource(
        ReplayConfig(
            path=Path(spec.target),
            loop=spec.flag("loop", False),
            realtime=spec.flag("realtime", False),
            speed=speed,
            start=start,
        )
    )
