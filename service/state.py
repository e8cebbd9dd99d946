"""What the routers share: the frame ring, the capture thread, the history store and the recorder.

One :class:`ServiceState` per app, built by ``create_app`` and handed to each router through the
``get_state`` dependency, so a route names what it uses instead of reaching into globals.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, HTTPException, Request

from service.frames import Capture, FrameGone, FrameRing, FrameUnknown, RingFrame
from service.recorder import Recorder
from history.store import Store


@dataclass
class ServiceState:
    ring: FrameRing
    capture: Capture
    store: Store
    recorder: Recorder
    started: float = field(default_factory=time.time)

    def entry(self, frame_id: int) -> RingFrame:
        """The ring frame ``frame_id``, or the HTTP error that says why it is not there (410 / 404)."""
        try:
            return self.ring.get(frame_id)
        except FrameGone as exc:
            raise HTTPException(410, exc.args[0]) from None
        except FrameUnknown as exc:
            raise HTTPException(404, exc.args[0]) from None


async def get_state(request: Request) -> ServiceState:
    """Async, so resolving it never waits for a worker thread."""
    return request.app.state.service


State = Annotated[ServiceState, Depends(get_state)]
