"""``/api/recordings``: record the live stream, and its status."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from service.deps import State
from service.schemas import RecordingIn, RecordingStatusOut, json_doc

router = APIRouter(prefix="/api/recordings", tags=["recordings"])


@router.get("", **json_doc(RecordingStatusOut))
def recording_status(state: State) -> dict[str, Any]:
    return state.recorder.status()


@router.post("", **json_doc(RecordingStatusOut))
def recording(state: State, body: RecordingIn) -> dict[str, Any]:
    return state.recorder.start(body.out) if body.action == "start" else state.recorder.stop()
