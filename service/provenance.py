"""Where a frame came from, as the history, the CSV and the page name it: the source kind, the
recording (a native recording's folder, a bag's or a video's file names) and the frame's index in it.

A recorded source (:data:`RECORDED_KINDS`) is one that can be paused, stepped and scrubbed; its frames
carry their index: a replay's in ``meta["replay"]["index"]``, a bag's and a video's in
``meta["frame_index"]``. A replayed frame's ``meta["source"]`` is the source it was recorded from
(e.g. "sim"), so the history's ``source`` of a recorded source is the spec it was opened with
(``replay:DIR``), which is what ``depthruler export --measurements`` matches recordings by.
"""

from __future__ import annotations

from pathlib import PurePath
from typing import Any

from device import SourceInfo
from measure import Frame

RECORDED_KINDS = ("replay", "bag", "video")


def recorded_index(frame: Frame) -> int | None:
    """The frame's 0-based index in its recording, None for a live source's frame."""
    replay = frame.meta.get("replay")
    if isinstance(replay, dict):
        return replay.get("index")
    if frame.meta.get("source") in ("bag", "video") and isinstance(frame.meta.get("frame_index"), int):
        return int(frame.meta["frame_index"])
    return None


def recording_name(frame: Frame) -> str:
    """The recording a frame was played from: a replay's folder name, a bag's file (or folder) name, a
    video's file names joined by ","; "" for a live source."""
    replay = frame.meta.get("replay")
    if isinstance(replay, dict) and replay.get("path"):
        return PurePath(str(replay["path"]).rstrip("/")).name
    if frame.meta.get("source") == "bag" and frame.meta.get("bag"):
        return PurePath(str(frame.meta["bag"]).rstrip("/")).name
    if frame.meta.get("source") == "video" and frame.meta.get("files"):
        return ",".join(PurePath(str(p)).name for p in frame.meta["files"])
    return ""


def source_kind(frame: Frame, info: SourceInfo | None, spec: str) -> str:
    """"replay", "bag", "video", "sim", "oak", "v4l2", ...: what the service was reading when it got ``frame``."""
    if isinstance(frame.meta.get("replay"), dict):
        return "replay"
    if info is not None and info.kind:
        return info.kind
    return spec.partition(":")[0].partition("?")[0] or str(frame.meta.get("source", ""))


def provenance(frame: Frame, info: SourceInfo | None, spec: str) -> tuple[str, dict[str, Any]]:
    """(the history's ``source``, the measurement's context: ``source_kind``, ``recording``, and for a
    recorded source ``frame_index`` and, for a replay, ``recorded_source``)."""
    kind = source_kind(frame, info, spec)
    meta_source = str(frame.meta.get("source", ""))
    context: dict[str, Any] = {"source_kind": kind, "recording": recording_name(frame)}
    index = recorded_index(frame)
    if index is not None:
        context["frame_index"] = index
    if kind in RECORDED_KINDS:
        if kind == "replay" and meta_source:
            context["recorded_source"] = meta_source
        return spec or f"{kind}:{context['recording']}", context
    return meta_source or spec, context
