"""Reading a recording: the manifest and frames.jsonl, every field type-checked and every path kept
inside the recording (a RecordingError names the file, the line and the field), and the frames."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, PinholeCamera

from device.base import SourceInfo
from device.errors import RecordingError
from device.formats.recording.format import (
    FORMAT,
    FORMAT_VERSION,
    FRAMES,
    MANIFEST,
    RAW_KEYS,
    RecordingNotFound,
    _camera_json,
    decode_confidence,
    decode_disparity,
    jsonable,
)

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
