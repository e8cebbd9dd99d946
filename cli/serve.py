"""``depthruler serve`` (the web service) and ``depthruler measure`` (one headless measurement).

Heavy imports (fastapi, uvicorn, cv2, backends) happen inside the commands so ``--help`` stays fast.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Optional

import typer
from typer.core import TyperCommand

LOOPBACK = ("127.0.0.1", "localhost", "::1")


def _fail(message: str, code: int = 2) -> None:
    typer.echo(f"depthruler: {message}", err=True)
    raise typer.Exit(code)


def check_listen(host: str, port: int) -> None:
    """Fail with a clear message, before anything starts, when ``host:port`` cannot be served
    (uvicorn would print the startup banner first and an OSError after it)."""
    import errno
    import socket

    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        with socket.create_server((host, port), family=family):  # SO_REUSEADDR, as uvicorn binds
            pass
    except socket.gaierror as exc:
        _fail(f"cannot resolve --host {host!r} ({exc.strerror}); use 127.0.0.1 or an address of this machine")
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            _fail(f"port {port} on {host} is already in use (another depthruler serve?); pass --port with a free port")
        _fail(f"cannot listen on {host}:{port} ({exc.strerror or exc}); pass another --host or --port")


# What `serve` shows with no camera: the simulated poster at 4 m with a tenth of the stress profile's
# wrong matches on contended pixels and 5 % holes on low texture, so the depth view reads as surfaces
# rather than static; the evaluations keep the stress profile (docs/decisions/demo-source.md).
DEMO_SIM = "sim:poster?distance=4&contention=0.1&hole_fraction=0.05"


def first_oak() -> str | None:
    """The spec of the first attached OAK, or None (also when discovery fails)."""
    try:
        from device import list_devices

        for info in list_devices():
            if info.kind == "oak":
                return str(info.extra.get("spec") or "oak")
    except Exception:  # noqa: BLE001 — discovery must never stop the service from starting
        pass
    return None


def auto_source() -> str:
    """The first attached OAK, else the simulated rig (``DEMO_SIM``, so ``serve`` always starts). Discovery runs in a
    child process: DepthAI's library and threads, about 190 MB resident, stay out of a server that
    does not use them."""
    import subprocess

    try:
        out = subprocess.run([sys.executable, "-c", "from cli.serve import first_oak; print(first_oak() or '')"],
                             capture_output=True, text=True, timeout=60)  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return DEMO_SIM
    lines = out.stdout.split() if out.returncode == 0 else []
    return lines[-1] if lines else DEMO_SIM


def setting(field: str, whole: bool):  # noqa: ANN201 — a typer parser
    """The parser of the flag for the :class:`service.config.ServerConfig` number ``field``: a value that
    is no number, or out of the field's bounds, is refused on one line naming the range it allows."""

    def parse(text: str) -> int | float:
        from service.config import ServerConfig, allowed_range

        word = "a whole number" if whole else "a number"
        try:
            value = int(text) if whole else float(text)
        except (TypeError, ValueError):
            raise typer.BadParameter(f"{text!r} is not {word}; give {word} {allowed_range(field)}") from None
        try:
            ServerConfig.model_validate({field: value})
        except ValueError:
            raise typer.BadParameter(f"{text} is out of range; give {word} {allowed_range(field)}") from None
        return value

    return parse


FLAGS = {"port": "--port", "ring_size": "--ring-size", "header_timeout_s": "--header-timeout",
         "body_timeout_s": "--body-timeout", "keep_alive_s": "--keep-alive", "max_connections": "--max-connections",
         "history_max_gb": "--history-max-gb", "host": "--host", "token": "--token", "db": "--db"}  # fmt: skip


class DefaultsInHelp(TyperCommand):
    """Fills the ``{name}`` fields of the options' help when the help is shown: the service's with
    ServerConfig's defaults, ``measure``'s with the method names and the frame limit. Imported only
    then, so ``depthruler --help`` does not load pydantic or the measuring core."""

    def format_help(self, ctx: Any, formatter: Any) -> None:
        from measure import MAX_FRAMES, METHODS, MeasureOptions
        from service.config import ServerConfig

        values = {k: f.default for k, f in ServerConfig.model_fields.items()}
        values |= {"methods": ", ".join(METHODS), "method": MeasureOptions().method, "max_frames": MAX_FRAMES}
        for param in self.params:
            if getattr(param, "help", None) and "{" in param.help:
                param.help = param.help.format(**values)
        super().format_help(ctx, formatter)


def serve(
    source: Optional[str] = typer.Option(None, "--source", "-s", help="Source spec, e.g. sim:poster?distance=3, oak, replay:DIR, or a recording folder, bag or video file. Left out: the config's source, else an attached OAK, else the simulator."),
    config: Optional[Path] = typer.Option(None, "--config", "-c", help="TOML config (see configs/*.toml); flags override it."),
    host: Optional[str] = typer.Option(None, help="Address to bind; left out, the config's or {host}. 0.0.0.0 exposes the service: set a token."),
    port: Optional[int] = typer.Option(None, parser=setting("port", True), metavar="INTEGER", help="TCP port; left out, the config's or {port}."),
    token: Optional[str] = typer.Option(None, envvar="DEPTHRULER_TOKEN", help="Require this token on /api (Bearer header or ?token=)."),
    db: Optional[Path] = typer.Option(None, help="SQLite history file; left out, the config's or {db}. Saved frames go to <db stem>-frames/ beside it."),
    recordings: Optional[Path] = typer.Option(None, help="The only folder recordings started from the API go into; left out, recordings/ next to the --db file."),
    history_max_gb: Optional[float] = typer.Option(None, "--history-max-gb", parser=setting("history_max_gb", False), metavar="FLOAT", help="Keep the saved frames under this many GB: the oldest unpinned frames are deleted first (their measurements stay). Left out: no cap."),
    insecure_no_token: bool = typer.Option(False, "--insecure-no-token", help="Serve on a non-loopback --host without a token: anyone who reaches the port can use the API."),
    allowed_host: Optional[list[str]] = typer.Option(None, "--allowed-host", help="Another Host name to answer (a DNS name of this machine); repeatable."),
    ring_size: Optional[int] = typer.Option(None, parser=setting("ring_size", True), metavar="INTEGER", help="Frames kept in the ring buffer; left out, the config's or {ring_size}."),
    header_timeout: Optional[float] = typer.Option(None, "--header-timeout", parser=setting("header_timeout_s", False), metavar="SECONDS", help="Seconds a connection has to send a request's headers, from its opening or the previous answer; left out, the config's or {header_timeout_s}. Then 408 and close."),
    body_timeout: Optional[float] = typer.Option(None, "--body-timeout", parser=setting("body_timeout_s", False), metavar="SECONDS", help="Seconds a request has to send its body after its headers; left out, the config's or {body_timeout_s}. Then 408 and close."),
    keep_alive: Optional[float] = typer.Option(None, "--keep-alive", parser=setting("keep_alive_s", False), metavar="SECONDS", help="Seconds an idle keep-alive connection stays open; left out, the config's or {keep_alive_s}."),
    max_connections: Optional[int] = typer.Option(None, "--max-connections", parser=setting("max_connections", True), metavar="INTEGER", help="Connections at once; left out, the config's or {max_connections} (fewer when the open-files limit is lower). Beyond it 503."),
) -> None:
    """Serve the measuring web page and HTTP API on a live source."""
    from service.app import create_app
    from pydantic import ValidationError

    from service.config import ConfigError, ServeConfig, ServerConfig, describe_validation, load_config
    from service.connections import serve as serve_app

    try:
        cfg = load_config(config) if config else ServeConfig()
        flags = {
            "host": host, "port": port, "token": token, "ring_size": ring_size, "header_timeout_s": header_timeout,
            "body_timeout_s": body_timeout, "keep_alive_s": keep_alive, "max_connections": max_connections,
        }  # fmt: skip
        overrides = {k: v for k, v in flags.items() if v is not None}
        if db is not None:
            overrides["db"] = str(db)
        if recordings is not None:
            overrides["recordings"] = str(recordings)
        if insecure_no_token:
            overrides["insecure_no_token"] = True
        if history_max_gb is not None:
            overrides["history_max_gb"] = history_max_gb
        if allowed_host:
            overrides["allowed_hosts"] = tuple(allowed_host)
        server = ServerConfig.model_validate({**cfg.server.model_dump(), **overrides})
    except ConfigError as exc:
        _fail(str(exc))
    except ValidationError as exc:  # the flags' parsers check each bound; this is the last word
        _fail(f"bad option: {describe_validation(exc, FLAGS)}")
    if server.host not in LOOPBACK and not server.token:
        if not server.insecure_no_token:
            _fail(
                f"--host {server.host} exposes the API to the network: set --token (or DEPTHRULER_TOKEN), "
                "or pass --insecure-no-token to serve it to anyone who reaches the port"
            )
        typer.echo(
            f"depthruler: warning: serving on {server.host} without a token (--insecure-no-token); "
            "anyone on the network can use the API.",
            err=True,
        )
    check_listen(server.host, server.port)  # after the token rule: a refused start never depends on the port
    from cli.specs import source_spec

    try:
        spec = source_spec(source) if source else (cfg.source or auto_source())
        app = create_app(spec, server)
    except Exception as exc:  # noqa: BLE001 — StoreError etc.: say what, don't dump a trace
        _fail(str(exc))
    typer.echo(f"depthruler: source {spec}; history {Path(server.db).resolve()}", err=True)
    typer.echo(f"depthruler: open http://{server.host}:{server.port}/ (it answers once the measuring core is loaded: "
               "seconds, or about half a minute on the first start after an install or an update, which builds it for this machine)", err=True)
    serve_app(app, server.host, server.port, server.limits, log_level=os.environ.get("DEPTHRULER_LOG", "warning"))


def _point(text: str, name: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise typer.BadParameter(f"{name} must be X,Y in pixels, e.g. 120,340 (got {text!r})") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise typer.BadParameter(f"{name} must be finite pixel coordinates (got {text!r})")
    return x, y


def measure(
    source: str = typer.Argument(..., metavar="SOURCE", help="Source spec (sim:poster?seed=1, replay:DIR, middlebury:DIR, oak, ...), or a recording folder, bag, video file or Middlebury scene folder."),
    p1: Optional[str] = typer.Option(None, "--p1", help="First point X,Y (pixels of the colour image) of a segment."),
    p2: Optional[str] = typer.Option(None, "--p2", help="Second point X,Y of the segment."),
    box: Optional[str] = typer.Option(None, "--box", help="Instead of a segment: a box's dimensions from a click X,Y on its top face."),
    height: Optional[str] = typer.Option(None, "--height", help="Instead of a segment: the height of the point X,Y above the plane it stands on (or the plane --on names)."),
    on: Optional[list[str]] = typer.Option(None, "--on", help="With --height: the plane to measure from, one click X,Y on it or three or more around a region of it (repeat)."),
    path: bool = typer.Option(False, "--path", help="Instead of a segment: the length of the polyline through the --point clicks (two or more)."),
    area: bool = typer.Option(False, "--area", help="Instead of a segment: the area of the polygon of the --point clicks (three or more, in order around it, on one plane)."),
    point: Optional[list[str]] = typer.Option(None, "--point", help="A click X,Y of a --path or --area (repeat, in order)."),
    frame: int = typer.Option(0, "--frame", "-n", min=0, help="Measure on this frame index (0 = first)."),
    method: str = typer.Option(None, "--method", "-m", help="One of {methods}; left out, {method}."),
    as_json: bool = typer.Option(False, "--json", help="Print the measurement as JSON."),
    timeout: float = typer.Option(5.0, min=0.01, help="Seconds to wait for each frame."),
    frames: int = typer.Option(1, "--frames", min=1, help="Measure over this many frames of a still scene (at most {max_frames}): the frame measured and the ones before it (robust method; with --frame K below N-1 the frame measured is N-1)."),
) -> None:
    """Measure between two points (or a box, a height, a path, an area) on one frame of a source, headless; prints the value, uncertainty and verdict."""
    from device import SourceError, open_source
    from device.base import FrameAccess
    from measure import MAX_FRAMES, MeasureError, MeasureOptions, measure_distance, measure_sequence, measure_shape
    from cli.shapes import segment_text, shape_json, shape_kind, shape_text
    from cli.specs import source_spec

    kind = shape_kind(box, height, path, area, point or [], on or [], p1 is not None or p2 is not None)
    if kind is None:
        if p1 is None or p2 is None:
            raise typer.BadParameter("a segment needs both --p1 and --p2", param_hint="--p1/--p2")
        a, b = _point(p1, "--p1"), _point(p2, "--p2")
    else:
        if frames > 1:
            raise typer.BadParameter("a shape is measured on one frame", param_hint="--frames")
        click = _point(box or height, "--box" if box else "--height") if (box or height) else None
        clicks = [_point(t, "--point") for t in point or []]
        base = [_point(t, "--on") for t in on or []]
    try:
        options = MeasureOptions() if method is None else MeasureOptions(method=method)
    except MeasureError as exc:
        raise typer.BadParameter(str(exc), param_hint="--method") from None
    if frames > MAX_FRAMES:
        raise typer.BadParameter(f"{frames} is more than the {MAX_FRAMES} frames one measurement pools", param_hint="--frames")
    frame = max(frame, frames - 1)
    read: list[Any] = []
    try:
        with open_source(source_spec(source)) as src:
            if isinstance(src, FrameAccess):  # a recording or bag: read the frames asked for, not every one before them
                if frame >= len(src):
                    _fail(f"cannot read frame {frame} of {source}: it has {len(src)} frames (0-{len(src) - 1})", 1)
                read = [src.frame(i) for i in range(frame - frames + 1, frame + 1)]
            else:
                for _ in range(frame + 1):
                    read = (read + [src.read(timeout)])[-frames:]
    except SourceError as exc:
        _fail(f"cannot read frame {frame} of {source}: {exc}", 1)
    f = read[-1]
    if kind is not None:
        from service.render import truth_json

        try:
            shape = measure_shape(f, kind, [click] if click else clicks, base or None, options)
        except MeasureError as exc:
            _fail(str(exc), 1)
        if as_json:
            typer.echo(shape_json(shape, kind, source, frame, truth_json(f.meta.get("truth"))))
        else:
            typer.echo("\n".join(shape_text(shape, kind)))
        return
    try:
        result = measure_sequence(read, a, b, options) if frames > 1 else measure_distance(f, a, b, options)
    except MeasureError as exc:
        _fail(str(exc), 1)
    from service.render import truth_json

    truth = truth_json(f.meta.get("truth"))
    if as_json:
        out: dict[str, Any] = {"source": source, "frame": frame, "p1": list(a), "p2": list(b), **result.to_dict()}
        if truth:
            out["truth"] = truth
        typer.echo(json.dumps(out))
        return
    typer.echo("\n".join(segment_text(result, frames, frame)))
    for w in result.warnings:
        typer.echo(f"warning: {w}")
    if truth and truth.get("length_m") is not None:
        ends = " and ".join(f"({p[0]:g},{p[1]:g})" for p in (truth.get("p1_px"), truth.get("p2_px")) if p)
        typer.echo(f"simulated truth: {truth.get('target')} is {truth['length_m']:.4f} m, between pixels {ends}")
    sys.stdout.flush()
