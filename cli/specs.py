"""Source specs typed on the command line: a bare recording folder or bag is read as one.

`depthruler replay` and `depthruler batch` take a recording folder as it is; :func:`source_spec`
gives `measure` and `check` the same: when what is typed before any ``?options`` is no source kind
but a folder with a ``manifest.json``, it becomes ``replay:FOLDER?options``, and a ROS bag
(``.bag``, ``.mcap``, ``.db3`` or a ROS 2 bag folder) ``bag:PATH?options``. Anything else is
returned as typed, for :func:`device.open_source` to read or refuse.
"""

from __future__ import annotations

from pathlib import Path


def source_spec(text: str) -> str:
    """``text``, or the replay or bag spec of the recording it names (module docstring)."""
    from device.base import BACKENDS

    head = text.strip().partition("?")[0]
    if not head or head.partition(":")[0].lower() in BACKENDS:
        return text
    path = Path(head).expanduser()
    if path.is_dir() and (path / "manifest.json").is_file():
        return f"replay:{text.strip()}"
    from device.sources.bag import is_bag_path

    return f"bag:{text.strip()}" if path.exists() and is_bag_path(path) else text
