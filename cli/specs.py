"""Source specs typed on the command line: a bare recording folder, bag, video file or scene is read as one.

`depthruler replay` and `depthruler batch` take a recording folder as it is; :func:`source_spec`
gives `measure`, `check`, `record` and `serve --source` the same. When what is typed before any
``?options`` names no source kind but an existing file or folder, its kind is told from what it holds:

- a folder with ``manifest.json`` (a recording): ``replay:PATH?options``;
- a ROS bag (``.bag``, ``.mcap``, ``.db3`` or a folder with ``metadata.yaml``): ``bag:PATH?options``;
- a video file (:data:`VIDEO_SUFFIXES`), or ``LEFT,RIGHT`` two of them: ``video:PATH?options``
  (the video source then asks for the calibration it needs);
- a folder with ``im0.png`` and ``calib.txt`` (a Middlebury scene): ``middlebury:PATH?options``;
- a folder of depth PNGs (``depth/`` or ``depth*.png``): ``depthpng:PATH?options``.

A path that exists but is none of these, or text that is neither a kind nor an existing path,
raises :class:`device.errors.SourceNotFound` saying what each kind needs. ``KIND:...`` with an
unknown kind and no path in front of the colon is returned as typed, for
:func:`device.open_source` to refuse with the list of kinds.
"""

from __future__ import annotations

from pathlib import Path

VIDEO_SUFFIXES = (".mkv", ".mp4", ".avi", ".mov", ".webm", ".m4v", ".mpg", ".mpeg", ".ts")


def _kinds() -> str:
    from device.base import BACKENDS

    return ", ".join(sorted(BACKENDS))


def _kind_of(path: Path) -> str | None:
    """The source kind that reads the existing ``path``, or None."""
    from device.sources.bag import is_bag_path

    if path.is_dir():
        if (path / "manifest.json").is_file():
            return "replay"
        if is_bag_path(path):
            return "bag"
        if (path / "im0.png").is_file() and (path / "calib.txt").is_file():
            return "middlebury"
        if (path / "depth").is_dir() or any(path.glob("depth*.png")):
            return "depthpng"
        return None
    if is_bag_path(path):
        return "bag"
    return "video" if path.suffix.lower() in VIDEO_SUFFIXES else None


def source_spec(text: str) -> str:
    """``text``, or the spec of the recording, bag, video or scene it names (module docstring);
    SourceNotFound for a path that is no source."""
    from device.base import BACKENDS
    from device.errors import SourceNotFound

    text = text.strip()
    head = text.partition("?")[0]
    kind, colon, _ = head.partition(":")
    if not head or kind.lower() in BACKENDS:
        return text
    try:  # a name the file system cannot hold (too long, a NUL byte, ~nouser) is no existing path
        parts = [Path(p).expanduser() for p in head.split(",")]
        if len(parts) == 2 and all(p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES for p in parts):
            return f"video:{text}"
        path = parts[0] if len(parts) == 1 else Path(head).expanduser()
        exists = path.exists()
        found = _kind_of(path) if exists else None
    except (OSError, ValueError, RuntimeError):
        exists, found = False, None
    if found:
        return f"{found}:{text}"
    if exists:
        what = "folder" if path.is_dir() else "file"
        holds = ("no recording (manifest.json), ROS 2 bag (metadata.yaml), Middlebury scene (im0.png, calib.txt) "
                 "or depth PNGs (depth/*.png)") if what == "folder" else (
                 f"neither a bag (.bag, .mcap, .db3) nor a video ({', '.join(VIDEO_SUFFIXES)})")  # fmt: skip
        raise SourceNotFound(f"{head} is a {what} but holds {holds}; point at one of those, or name its kind "
                             f"as KIND:{head} with KIND one of {_kinds()}")
    if colon and "/" not in kind and "\\" not in kind:
        return text  # KIND:... with an unknown kind: open_source lists the kinds
    raise SourceNotFound(f"{head!r} is no source kind and no existing file or folder; fix the path, or give a spec "
                         f"KIND:... with KIND one of {_kinds()} (e.g. replay:rec/desk, bag:run.bag, video:pair.mkv)")
