"""``/api/health`` and ``/api/source``: is the service up, and what is the source doing."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

from service.deps import State
from service.playback import home_spec, play_home, play_recording
from service.schemas import HealthOut, ReplayIn, ReplayStatusOut, SourceOpenIn, SourceStatusOut, json_doc

router = APIRouter(prefix="/api", tags=["health"])
SOURCE_DOWN = ("disconnected", "reconnecting", "failed")


@router.get("/health", **json_doc(HealthOut))
async def health(state: State) -> dict[str, Any]:
    """``status`` is "ok", or "degraded" with the ``reasons``: the next frame would not fit on the
    history's disk (measurements answer 507; compared with the free bytes at every call), or the
    source is down (``source_state``, ``source_message``). ``recording_error`` is why the last
    recording stopped by itself. Answered without the token, so a monitor can poll it."""
    source = state.capture.status()
    latest = state.ring.latest()
    if state.store.frame_size_known:
        # on the loop: behind the worker threads an export or 32 measuring pages keep busy, a monitor's
        # poll would wait for a thread
        disk = state.store.status()
    else:
        disk = await run_in_threadpool(state.store.status, latest.frame if latest else None)
    reasons = [disk["degraded"]] if disk["degraded"] else []
    if source["state"] in SOURCE_DOWN:
        reasons.append(f"the source is {source['state']}: {source['message']}".rstrip(": "))
    recording = state.recorder.status()
    return {
        "status": "degraded" if reasons else "ok",
        "reason": "; ".join(reasons),
        "reasons": reasons,
        "source_state": source["state"],
        "source_message": source["message"],
        "recording_error": "" if recording["active"] else recording["error"],
        "free_bytes": disk["free_bytes"],
        "next_frame_bytes": disk["need_bytes"],
        "frames": len(state.ring),
        "ring_bytes": state.ring.nbytes,
        "kernels": state.kernels,
        "uptime_s": time.time() - state.started,
    }


@router.get("/source", **json_doc(SourceStatusOut))
def source_status(state: State) -> dict[str, Any]:
    return {**state.capture.status(), "recording": state.recorder.status(), "home": home_spec(state)}


@router.post("/source", **json_doc(SourceStatusOut))
def open_source(state: State, body: SourceOpenIn) -> dict[str, Any]:
    """Play ``recording``, a folder of the recordings root, in place of the server's source (an active
    recording stops first); ``recording: null`` goes back to the server's source. 404 when the folder
    is no recording, 422 for a name that is not a plain folder inside the root."""
    if body.recording is None:
        play_home(state)
    else:
        play_recording(state, body.recording)
    return source_status(state)


@router.post("/source/replay", **json_doc(ReplayStatusOut))
def replay_control(state: State, body: ReplayIn) -> dict[str, Any]:
    """Pause, play, step or seek a replay; answers the replay status (``paused``, ``index``, ``frames``)."""
    return state.capture.control(body.action, body.index)
