"""The measuring service: FastAPI app over a live source, a frame ring buffer and SQLite history.

``create_app(source, settings)`` builds the app (settings: one ``service.config.ServerConfig``);
``depthruler serve`` runs it with uvicorn.
The routes live in ``service.routers`` (one module per resource) and share one
:class:`service.state.ServiceState` through :mod:`service.deps`. The web page in ``static/`` uses
only the API. Errors carry a ``detail`` message saying what to change; :mod:`service.errors` gives
each domain error its status (410 for a frame evicted from the ring, 404 for an unknown id, 422
for bad input, 429 while every measurement worker is busy, 507 for a full disk), the token middleware 401, :mod:`service.guard` 400/403/413/415.
"""

from __future__ import annotations

import gc
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from device import Source, make_source
from measure import warm_up

from history.store import Store

from service import errors
from service.config import ServerConfig
from service.capture import Capture
from service.frames import FrameRing
from service.guard import RequestGuard, allowed_hosts_for
from service.recorder import Recorder
from service.routers import checks, frames, health, measurements, options, recordings, shapes
from service.state import ServiceState
from service.workers import MeasurePool

STATIC_DIR = Path(__file__).resolve().parent / "static"
log = logging.getLogger("depthruler")


# create_app's keyword names that differ from ServerConfig's, with the conversion
_LEGACY: dict[str, tuple[str, Callable[[Any], Any]]] = {
    "db_path": ("db", str),
    "recordings_dir": ("recordings", str),
    "history_max_bytes": ("history_max_gb", lambda b: None if b is None else b / 1e9),
}


def create_app(source: str | Callable[[], Source], settings: ServerConfig | None = None, **overrides: Any) -> FastAPI:
    """The service app on ``source`` (a spec string or a factory of unopened sources), run as
    ``settings`` say (:class:`service.config.ServerConfig`: history, ring, capture rate, token,
    Host names, limits). Keyword ``overrides`` replace single settings, by ServerConfig name
    (``ring_size=8``; also ``db_path``, ``recordings_dir`` and ``history_max_bytes``); a wrong
    name or value raises pydantic's ValidationError. The app answers ``Host`` names of
    ``guard.allowed_hosts_for(settings.host, settings.allowed_hosts)``."""
    settings = settings or ServerConfig()
    if overrides:
        for old, (new, convert) in _LEGACY.items():
            if old in overrides:
                overrides[new] = convert(overrides.pop(old))
        settings = ServerConfig.model_validate({**settings.model_dump(), **overrides})
    spec = source if isinstance(source, str) else getattr(source, "__name__", "custom")
    factory: Callable[[], Source] = (lambda: make_source(source)) if isinstance(source, str) else source  # type: ignore[arg-type]
    ring = FrameRing(
        settings.ring_size, settings.max_frozen, settings.keep_viewed, settings.max_waiters, freeze_ttl_s=settings.freeze_ttl_s
    )
    capture = Capture(
        factory, ring, spec=spec, fps=settings.capture_fps,
        backoff_initial_s=settings.reconnect_initial_s, backoff_max_s=settings.reconnect_max_s,
    )  # fmt: skip
    store = Store(settings.db, max_bytes=settings.history_max_bytes)
    recorder = Recorder(capture, settings.recordings_dir)
    measures = MeasurePool(settings.measure_workers, settings.measure_queue, settings.measure_nice)
    state = ServiceState(ring=ring, capture=capture, store=store, recorder=recorder, measures=measures, home=(factory, spec))

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        # the first person's click pays neither imports nor loading compiled kernels (docs/decisions/service-speed.md)
        kernels = warm_up()
        state.kernels = "numba, just in time" if kernels.startswith("jit") else "built ahead of time"
        if kernels.startswith("jit: "):
            log.warning("depthruler: measuring with numba's just-in-time kernels, which keep LLVM in the process: %s", kernels[5:])
        # The objects of the imports and the app live as long as the process: keep them out of the
        # collector's full passes, which otherwise stop every thread (docs/decisions/service-speed.md).
        # Frozen already (by the program that runs this app, or by an app serving in this process):
        # left as it is, so neither a full pass is paid again nor the other's objects unfrozen at the end.
        freezes = gc.get_freeze_count() == 0
        if freezes:
            gc.collect()
            gc.freeze()
        capture.start()
        try:
            yield
        finally:
            if recorder.status()["active"]:
                recorder.stop()
            capture.stop()
            measures.close()
            state.live_images.shutdown(wait=True, cancel_futures=True)
            store.close()
            if freezes:
                gc.unfreeze()  # a process that builds apps one after another can free them again

    app = FastAPI(title="depthruler", summary="Click two points, get a robust 3D length.", lifespan=lifespan)
    app.state.service = state
    app.state.ring, app.state.capture, app.state.store, app.state.recorder = ring, capture, store, recorder

    errors.install(app)

    for module in (health, frames, measurements, shapes, recordings, checks, options):
        app.include_router(module.router)
    app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="static")
    hosts = allowed_hosts_for(settings.host, settings.allowed_hosts)
    app.add_middleware(RequestGuard, allowed_hosts=hosts, max_body_bytes=settings.max_body_bytes, token=settings.token)  # outermost
    return app
