"""The measuring service: FastAPI app over a live source, a frame ring buffer and SQLite history.

``create_app(source, db_path=...)`` builds the app; ``depthruler serve`` runs it with uvicorn.
Endpoints are fixed by ARCHITECTURE.md "Service"; the web page in ``static/`` uses only them.
Errors carry a ``detail`` message saying what to change: 410 for a frame evicted from the ring,
404 for an unknown id, 422 for bad input (types, NaN, points outside the image), 401 for a token.
"""

from __future__ import annotations

import hmac
import math
import threading
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Any, Literal

import cv2
import numpy as np
from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, Strict

from device import Source, make_source
from measure import Frame, MeasureError, MeasureOptions, PinholeCamera, measure_distance

from .frames import Capture, FrameGone, FrameRing, FrameUnknown, RingFrame
from .store import Store, StoreError

STATIC_DIR = Path(__file__).resolve().parent / "static"
THUMB_WIDTH = 240

FiniteNumber = Annotated[float, Strict(), Field(allow_inf_nan=False)]


class OptionsIn(BaseModel):
    """Measurement options (MeasureOptions); every field optional."""

    model_config = ConfigDict(extra="forbid")
    method: Literal["robust", "paper", "basic"] = "robust"
    support_fraction: Annotated[float, Field(ge=0.5, le=1.0, allow_inf_nan=False)] = 0.5
    window: Annotated[int, Strict(), Field(ge=1, le=51)] = 5
    extension_px: Annotated[int, Strict(), Field(ge=3, le=500)] = 25
    gap_detection: Annotated[bool, Strict()] = True
    seed: Annotated[int, Strict(), Field(ge=0)] = 0


class MeasureIn(BaseModel):
    """``POST /api/measure`` body: the frame id and two points in pixels of its colour image."""

    model_config = ConfigDict(extra="forbid")
    frame_id: Annotated[int, Strict()]
    p1: tuple[FiniteNumber, FiniteNumber]
    p2: tuple[FiniteNumber, FiniteNumber]
    options: OptionsIn = OptionsIn()


class RecordingIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    action: Literal["start", "stop"]
    out: str | None = None


def encode_png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def colorize_disparity(disparity: np.ndarray) -> np.ndarray:
    """BGR image of a disparity map (px): turbo colour map over its 1st..99th percentile; no data is black."""
    valid = np.isfinite(disparity)
    out = np.zeros(disparity.shape + (3,), np.uint8)
    if not valid.any():
        return out
    lo, hi = np.percentile(disparity[valid], [1, 99])
    scale = 255.0 / max(hi - lo, 1e-6)
    norm = np.clip((np.where(valid, disparity, lo) - lo) * scale, 0, 255).astype(np.uint8)
    mapped = cv2.applyColorMap(norm, cv2.COLORMAP_TURBO)
    out[valid] = mapped[valid]
    return out


def make_thumb(frame: Frame, p1: tuple[float, float], p2: tuple[float, float]) -> bytes:
    """A small PNG of the frame with the measured segment drawn on it."""
    h, w = frame.disparity.shape
    s = THUMB_WIDTH / w
    small = cv2.resize(frame.image, (THUMB_WIDTH, max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    a = (round((p1[0] + 0.5) * s * 16), round((p1[1] + 0.5) * s * 16))
    b = (round((p2[0] + 0.5) * s * 16), round((p2[1] + 0.5) * s * 16))
    cv2.line(small, a, b, (0, 0, 0), 4, cv2.LINE_AA, shift=4)
    cv2.line(small, a, b, (40, 220, 255), 2, cv2.LINE_AA, shift=4)
    for p in (a, b):
        cv2.circle(small, p, 4 * 16, (40, 220, 255), -1, cv2.LINE_AA, shift=4)
    return encode_png(small)


def truth_json(truth: Any) -> dict[str, Any] | None:
    """The simulator's ground truth (a Truth object, or the JSON summary a recording keeps)."""
    if truth is None:
        return None
    keys = ("p1_px", "p2_px", "p1_m", "p2_m", "length_m", "target", "is_gap")
    get = truth.get if isinstance(truth, dict) else (lambda k: getattr(truth, k, None))
    out: dict[str, Any] = {}
    for k in keys:
        v = get(k)
        if isinstance(v, (tuple, list, np.ndarray)):
            v = [float(x) for x in np.asarray(v, dtype=float).ravel()]
        elif isinstance(v, (np.floating, np.integer, np.bool_)):
            v = v.item()
        out[k] = v
    return out


def frame_json(entry: RingFrame) -> dict[str, Any]:
    f = entry.frame
    h, w = f.disparity.shape
    meta = {k: v for k, v in dict(f.meta).items() if isinstance(v, (str, int, float, bool)) and k != "truth"}
    return {
        "id": entry.id,
        "uid": entry.uid,
        "width": w,
        "height": h,
        "timestamp": float(f.timestamp),
        "received": entry.received,
        "frozen": entry.frozen,
        "source": str(f.meta.get("source", "")),
        "meta": {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in meta.items()},
        "truth": truth_json(f.meta.get("truth")),
    }


class Recorder:
    """Writes the live frames to a recording (device.recording.RecordingWriter) while started."""

    def __init__(self, capture: Capture, default_dir: Path) -> None:
        self.capture = capture
        self.default_dir = default_dir
        self._lock = threading.Lock()
        self._writer: Any = None
        self._path: Path | None = None
        self._frames = 0
        self._error = ""

    def status(self) -> dict[str, Any]:
        with self._lock:
            return {
                "active": self._writer is not None,
                "path": str(self._path) if self._path else None,
                "frames": self._frames,
                "error": self._error,
            }

    def start(self, out: str | None) -> dict[str, Any]:
        try:
            from device.recording import RecordingWriter
        except ImportError as exc:
            raise HTTPException(503, f"recording is not available in this build ({exc})") from exc
        info = self.capture.info
        if info is None:
            raise HTTPException(409, "the source has not delivered a frame yet; start recording once it streams")
        path = Path(out) if out else self.default_dir / time.strftime("%Y%m%d-%H%M%S")
        with self._lock:
            if self._writer is not None:
                raise HTTPException(409, f"already recording to {self._path}; stop it first")
            try:
                self._writer = RecordingWriter(path, info)
            except Exception as exc:  # noqa: BLE001 — RecordingError or OSError: report, don't crash
                raise HTTPException(400, f"cannot record to {path}: {exc}") from exc
            self._path, self._frames, self._error = path, 0, ""
        self.capture.sinks.append(self._write)
        return self.status()

    def stop(self) -> dict[str, Any]:
        with self._lock:
            if self._writer is None:
                raise HTTPException(409, "not recording; start a recording first")
            self._close()
        return self.status()

    def _close(self) -> None:
        if self._write in self.capture.sinks:
            self.capture.sinks.remove(self._write)
        writer, self._writer = self._writer, None
        try:
            writer.close()
        except Exception as exc:  # noqa: BLE001
            self._error = f"closing the recording failed: {exc}"

    def _write(self, frame: Frame) -> None:
        with self._lock:
            if self._writer is None:
                return
            try:
                self._writer.write(frame)
                self._frames += 1
            except Exception as exc:  # noqa: BLE001 — a full disk must stop the recording, not the stream
                self._error = f"recording stopped: {exc}"
                self._close()


def _validation_message(exc: RequestValidationError) -> tuple[str, list[dict[str, str]]]:
    errors = []
    for e in exc.errors():
        loc = ".".join(str(p) for p in e.get("loc", ()) if p != "body") or "body"
        errors.append({"loc": loc, "msg": str(e.get("msg", "invalid")), "input": repr(e.get("input"))[:80]})
    text = "; ".join(f"{e['loc']}: {e['msg']} (got {e['input']})" for e in errors)
    return text, errors


def _warm_up_measurement() -> None:
    """Measure once on a tiny tilted plane so the first person's click does not pay for imports and
    lazily built constants (~0.3 s)."""
    h, w = 48, 64
    camera = PinholeCamera(fx=60.0, fy=60.0, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)
    disparity = np.tile(np.linspace(8.0, 12.0, w, dtype=np.float32), (h, 1))
    frame = Frame(image=np.zeros((h, w, 3), np.uint8), disparity=disparity, camera=camera, baseline_m=0.1)
    for method in ("robust", "paper"):
        measure_distance(frame, (5.0, 20.0), (58.0, 28.0), MeasureOptions(method=method))


def create_app(
    source: str | Callable[[], Source],
    *,
    db_path: str | Path = "depthruler.db",
    token: str = "",
    ring_size: int = 32,
    max_frozen: int = 16,
    capture_fps: float = 15.0,
    reconnect_initial_s: float = 0.5,
    reconnect_max_s: float = 10.0,
) -> FastAPI:
    """The service app on ``source`` (a spec string or a factory of unopened sources)."""
    spec = source if isinstance(source, str) else getattr(source, "__name__", "custom")
    factory: Callable[[], Source] = (lambda: make_source(source)) if isinstance(source, str) else source  # type: ignore[arg-type]
    ring = FrameRing(ring_size, max_frozen)
    capture = Capture(
        factory, ring, spec=spec, fps=capture_fps, backoff_initial_s=reconnect_initial_s, backoff_max_s=reconnect_max_s
    )
    store = Store(db_path)
    recorder = Recorder(capture, Path(db_path).resolve().parent / "recordings")
    started = time.time()

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        _warm_up_measurement()
        capture.start()
        try:
            yield
        finally:
            if recorder.status()["active"]:
                recorder.stop()
            capture.stop()
            store.close()

    app = FastAPI(title="depthruler", summary="Click two points, get a robust 3D length.", lifespan=lifespan)
    app.state.ring, app.state.capture, app.state.store, app.state.recorder = ring, capture, store, recorder

    @app.exception_handler(RequestValidationError)
    async def _invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
        text, errors = _validation_message(exc)
        return JSONResponse({"detail": text, "errors": errors}, status_code=422)

    if token:

        @app.middleware("http")
        async def _auth(request: Request, call_next: Any) -> Response:
            path = request.url.path
            if path.startswith("/api/") and path != "/api/health":
                header = request.headers.get("authorization", "")
                given = header[7:].strip() if header.lower().startswith("bearer ") else request.query_params.get("token", "")
                if not hmac.compare_digest(given.encode(), token.encode()):
                    return JSONResponse(
                        {"detail": "missing or wrong token: send 'Authorization: Bearer <token>' or add ?token=<token>"},
                        status_code=401,
                        headers={"WWW-Authenticate": "Bearer"},
                    )
            return await call_next(request)

    def entry_or_error(fid: int) -> RingFrame:
        try:
            return ring.get(fid)
        except FrameGone as exc:
            raise HTTPException(410, exc.args[0]) from None
        except FrameUnknown as exc:
            raise HTTPException(404, exc.args[0]) from None

    @app.get("/api/health")
    def health() -> dict[str, Any]:
        status = capture.status()
        return {
            "status": "ok",
            "source_state": status["state"],
            "frames": len(ring),
            "uptime_s": time.time() - started,
            "store_errors": store.write_errors[-5:],
        }

    @app.get("/api/source")
    def source_status() -> dict[str, Any]:
        return {**capture.status(), "recording": recorder.status()}

    @app.get("/api/frames/latest")
    def latest(after: int = 0, wait: Annotated[float, Query(ge=0, le=10)] = 0.0) -> dict[str, Any]:
        entry = ring.wait_latest(after, wait) if wait else ring.latest()
        if entry is None:
            status = capture.status()
            raise HTTPException(
                503, f"no frame yet from {status['spec'] or 'the source'} (state {status['state']}) {status['message']}".strip()
            )
        return frame_json(entry)

    @app.get("/api/frames/{frame_id}")
    def frame_info(frame_id: int) -> dict[str, Any]:
        return frame_json(entry_or_error(frame_id))

    @app.get("/api/frames/{frame_id}/color.png")
    def color_png(frame_id: int) -> Response:
        entry = entry_or_error(frame_id)
        data = entry.encoded("color.png", lambda f: encode_png(f.image))
        return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})

    @app.get("/api/frames/{frame_id}/disparity.png")
    def disparity_png(frame_id: int) -> Response:
        entry = entry_or_error(frame_id)
        data = entry.encoded("disparity.png", lambda f: encode_png(colorize_disparity(f.disparity)))
        return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})

    @app.post("/api/frames/{frame_id}/freeze")
    def freeze(frame_id: int) -> dict[str, Any]:
        entry_or_error(frame_id)
        return frame_json(ring.freeze(frame_id, True))

    @app.delete("/api/frames/{frame_id}/freeze")
    def unfreeze(frame_id: int) -> dict[str, Any]:
        entry_or_error(frame_id)
        return frame_json(ring.freeze(frame_id, False))

    @app.post("/api/measure")
    def measure(body: MeasureIn) -> dict[str, Any]:
        entry = entry_or_error(body.frame_id)
        frame = entry.frame
        h, w = frame.disparity.shape
        for name, (x, y) in (("p1", body.p1), ("p2", body.p2)):
            if not (0 <= x <= w - 1 and 0 <= y <= h - 1):
                raise HTTPException(
                    422, f"{name}=({x:g}, {y:g}) is outside the {w}x{h} image of frame {entry.id}; use 0<=x<={w - 1}, 0<=y<={h - 1}"
                )
        options = body.options.model_dump()
        try:
            result = measure_distance(frame, body.p1, body.p2, MeasureOptions(**options))
        except MeasureError as exc:
            raise HTTPException(422, str(exc)) from None
        record = store.add(
            frame_id=entry.id,
            frame_uid=entry.uid,
            source=str(frame.meta.get("source", "")) or capture.spec,
            p1=body.p1,
            p2=body.p2,
            options=options,
            result=result.to_dict(),
            thumb=make_thumb(frame, body.p1, body.p2),
        )
        store.ensure_frame(entry.uid, frame)  # after the row exists: the writer drops frames nobody refers to
        return record

    @app.get("/api/measurements.csv")
    def measurements_csv() -> PlainTextResponse:
        return PlainTextResponse(
            store.csv(),
            media_type="text/csv",
            headers={"Content-Disposition": 'attachment; filename="depthruler-measurements.csv"'},
        )

    @app.get("/api/measurements", response_model=None)
    def measurements(format: Literal["json", "csv"] = "json", limit: Annotated[int, Query(ge=1)] = 1000) -> Any:
        if format == "csv":
            return measurements_csv()
        return store.list(limit)

    def record_or_404(mid: int) -> dict[str, Any]:
        record = store.get(mid)
        if record is None:
            raise HTTPException(404, f"no measurement {mid}; GET /api/measurements lists them")
        return record

    @app.get("/api/measurements/{mid}")
    def measurement(mid: int) -> dict[str, Any]:
        return record_or_404(mid)

    @app.delete("/api/measurements/{mid}")
    def delete_measurement(mid: int) -> dict[str, Any]:
        if not store.delete(mid):
            raise HTTPException(404, f"no measurement {mid}; GET /api/measurements lists them")
        return {"deleted": mid}

    @app.get("/api/measurements/{mid}/thumb.png")
    def thumb(mid: int) -> Response:
        record_or_404(mid)
        data = store.thumb(mid)
        if data is None:
            raise HTTPException(404, f"measurement {mid} has no thumbnail")
        return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})

    @app.post("/api/measurements/{mid}/open")
    def reopen(mid: int) -> dict[str, Any]:
        """Put the saved frame of a measurement back into the ring (frozen) to view or re-measure it."""
        record = record_or_404(mid)
        try:
            saved = store.frame(record["frame_uid"])
        except StoreError as exc:
            raise HTTPException(404, str(exc)) from None
        entry = ring.push(saved, frozen=True, uid=record["frame_uid"])
        return {"frame": frame_json(entry), "measurement": record}

    @app.get("/api/recordings")
    def recording_status() -> dict[str, Any]:
        return recorder.status()

    @app.post("/api/recordings")
    def recording(body: RecordingIn) -> dict[str, Any]:
        return recorder.start(body.out) if body.action == "start" else recorder.stop()

    app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="static")
    return app
