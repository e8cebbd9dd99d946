"""``/api/health`` and ``/api/source``: is the service up, and what is the source doing."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, HTTPException
from starlette.concurrency import run_in_threadpool

from service.frames import ReplayControlError
from service.schemas import HealthOut, ReplayIn, ReplayStatusOut, SourceStatusOut, json_doc
from service.state import State

router = APIRouter(prefix="/api", tags=["health"])


@router.get("/health", **json_doc(HealthOut))
async def health(state: State) -> dict[str, Any]:
    """``status`` is "ok", or "degraded" with a ``reason`` (the history's disk is full: measurements
    answer 507 until space comes back, checked on every call)."""
    status = state.capture.status()
    degraded = (await run_in_threadpool(state.store.status))["degraded"] if state.store.degraded else ""
    return {
        "status": "degraded" if degraded else "ok",
        "reason": degraded,
        "source_state": status["state"],
        "frames": len(state.ring),
        "uptime_s": time.time() - state.started,
    }


@router.get("/source", **json_doc(SourceStatusOut))
def source_status(state: State) -> dict[str, Any]:
    return {**state.capture.status(), "recording": state.recorder.status()}


@router.post("/source/replay", **json_doc(ReplayStatusOut))
def replay_control(state: State, body: ReplayIn) -> dict[str, Any]:
    """Pause, play, step or seek a replay; answers the replay status (``paused``, ``index``, ``frames``)."""
    try:
        return state.capture.control(body.action, body.index)
    except ReplayControlError as exc:
        raise HTTPException(409 if "not a replay" in str(exc) else 422, str(exc)) from None
