"""The routes' dependencies: the service state, a frame of the ring by its path id, a stored
measurement by its path id. A lookup that fails raises the domain's own exception
(:class:`service.frames.FrameGone`, :class:`history.errors.MeasurementUnknown`, ...), which
:mod:`service.errors` answers."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, Path, Request

from service.frames import RingFrame
from service.schemas import MAX_ID
from service.state import ServiceState


async def get_state(request: Request) -> ServiceState:
    """Async, so resolving it never waits for a worker thread."""
    return request.app.state.service


State = Annotated[ServiceState, Depends(get_state)]
FrameId = Annotated[int, Path(ge=0, le=MAX_ID, description="A frame id of the ring (GET /api/frames/latest).")]
MeasurementId = Annotated[int, Path(ge=0, le=MAX_ID, description="A stored measurement's id.")]


async def ring_frame(state: State, frame_id: FrameId) -> RingFrame:
    """The ring's frame ``frame_id`` (a lookup under a lock, never blocking: async)."""
    return state.ring.get(frame_id)


def stored_measurement(state: State, mid: MeasurementId) -> dict[str, Any]:
    """The full record of measurement ``mid`` (a database read: on a worker thread)."""
    return state.store.record(mid)


FrameDep = Annotated[RingFrame, Depends(ring_frame)]
MeasurementDep = Annotated[dict[str, Any], Depends(stored_measurement)]
