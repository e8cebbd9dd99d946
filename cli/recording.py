"""`depthruler record`, `depthruler replay` and `depthruler export`: capture sessions on disk.

Heavy imports (cv2, numpy, rich, the sources) happen inside the commands so `depthruler --help` stays fast.
"""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path
from typing import Optional

import typer


def _fail(message: str) -> typer.Exit:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    return typer.Exit(code=1)


def _human_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def record(
    source: str = typer.Option(..., "--source", "-s", help="Source spec, e.g. sim:poster, oak, v4l2:/dev/video0, middlebury:DIR, or a recording folder, bag or video file"),
    out: Path = typer.Option(..., "--out", "-o", help="Recording directory to create"),
    frames: Optional[int] = typer.Option(None, "--frames", "-n", min=1, help="Stop after this many frames"),
    seconds: Optional[float] = typer.Option(None, "--seconds", min=0.0, help="Stop after this many seconds"),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing recording in --out"),
    keep_raw: bool = typer.Option(False, "--keep-raw", help="Also keep the raw stereo pair (meta raw_left/raw_right)"),
    timeout: float = typer.Option(2.0, "--timeout", min=0.01, help="Seconds to wait for each frame"),
) -> None:
    """Record frames from a source into a directory; Ctrl-C stops cleanly and keeps the recording valid."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from device import make_source
    from device.errors import SourceDisconnected, SourceError, SourceTimeout
    from device.formats.recording import RecordingWriter

    if (frames is None) == (seconds is None):
        raise typer.BadParameter("give exactly one of --frames N or --seconds S")
    stop = {"requested": False}

    def on_sigint(signum: int, stack: object) -> None:
        # Finish the frame in flight, then stop: a second Ctrl-C interrupts at once.
        if stop["requested"]:
            raise KeyboardInterrupt
        stop["requested"] = True

    reason = "done"
    timeouts = 0
    from cli.specs import source_spec

    try:
        src = make_source(source_spec(source))
        src.open()
    except SourceError as exc:
        raise _fail(str(exc)) from exc
    try:
        previous = signal.signal(signal.SIGINT, on_sigint)
    except ValueError:  # not the main thread: Ctrl-C stays a KeyboardInterrupt, handled below
        previous = None
    try:
        try:
            writer = RecordingWriter(out, src.info, overwrite=overwrite, keep_raw=keep_raw)
        except SourceError as exc:
            raise _fail(str(exc)) from exc
        start = time.monotonic()
        try:
            with Progress(
                TextColumn("recording"),
                BarColumn(),
                MofNCompleteColumn() if frames else TextColumn("{task.completed:.1f}/{task.total:.1f} s"),
                TextColumn("{task.fields[n]} frames"),
                TimeElapsedColumn(),
                transient=True,
            ) as progress:
                task = progress.add_task("record", total=frames or seconds, n=0)
                while True:
                    elapsed = time.monotonic() - start
                    if stop["requested"]:
                        reason = "stopped by Ctrl-C"
                        break
                    if frames is not None and writer.frames_written >= frames:
                        break
                    if seconds is not None and elapsed >= seconds:
                        break
                    try:
                        frame = src.read(timeout_s=timeout)
                    except SourceTimeout as exc:
                        timeouts += 1
                        if timeouts >= 5:
                            reason = f"stopped: no frame for {timeouts} reads in a row ({exc})"
                            break
                        continue
                    except SourceDisconnected as exc:
                        reason = f"stopped: {exc}"
                        break
                    timeouts = 0
                    writer.write(frame)
                    done = writer.frames_written if frames else min(time.monotonic() - start, seconds or 0.0)
                    progress.update(task, completed=done, n=writer.frames_written)
        except KeyboardInterrupt:
            reason = "interrupted by Ctrl-C"
        except SourceError as exc:
            writer.close()
            raise _fail(str(exc)) from exc
        finally:
            wall = time.monotonic() - start
            writer.close()
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        src.close()
    from device.formats.recording import open_recording

    rec = open_recording(writer.path)
    n = len(rec)
    size = rec.size_bytes()
    fps = n / wall if wall > 0 else 0.0
    typer.echo(f"{reason}: {n} frames in {wall:.1f} s ({fps:.1f} fps) -> {writer.path}")
    typer.echo(f"size on disk {_human_bytes(size)} ({_human_bytes(size / max(n, 1))} per frame)")


def replay(
    path: Path = typer.Argument(..., metavar="RECORDING", help="Recording directory"),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON"),
) -> None:
    """Inspect a recording: manifest, frames, problems and how much of each disparity is valid.
    A ROS bag (.bag, .mcap, .db3 or a ROS 2 bag folder) shows its layout, topics and frame pairs instead."""
    from device.sources.bag import is_bag_path
    from device.errors import SourceError
    from device.formats.recording import open_recording, summarize

    if is_bag_path(path):
        _replay_bag(path, as_json)
        return
    try:
        info = summarize(open_recording(path))
    except SourceError as exc:
        raise _fail(str(exc)) from exc
    if as_json:
        typer.echo(json.dumps(info, indent=2))
    else:
        src = info["source"]
        cam = info["camera"] or {}
        vd = info["valid_disparity"]
        typer.echo(f"recording  {info['path']} (format {info['format_version']}, created {info['created']})")
        typer.echo(f"source     {src['kind']} {src['name']} {src['serial']}".rstrip())
        if cam:
            typer.echo(
                f"camera     {cam['width']}x{cam['height']} fx={cam['fx']:.2f} fy={cam['fy']:.2f} "
                f"cx={cam['cx']:.2f} cy={cam['cy']:.2f}  baseline {info['baseline_m']} m  doffs {info['doffs']}"
            )
        fps = f"{info['fps']:.1f} fps" if info["fps"] else "no timing"
        typer.echo(f"frames     {info['frames']} over {info['duration_s']:.2f} s ({fps}); {_human_bytes(info['size_bytes'])}")
        if vd["median"] is not None:
            typer.echo(f"valid disparity per frame: min {vd['min']:.1%}  median {vd['median']:.1%}  max {vd['max']:.1%}")
        if not info["complete"]:
            typer.echo("note       the writer did not close it (crash or still recording); the complete frames are all usable")
        for p in info["problems"]:
            typer.secho(f"problem    {p}", fg=typer.colors.YELLOW)
    if info["unreadable_frames"]:
        raise typer.Exit(code=1)


def _replay_bag(path: Path, as_json: bool) -> None:
    from device.sources.bag import summarize_bag
    from device.errors import SourceError

    try:
        info = summarize_bag(path)
    except SourceError as exc:
        raise _fail(str(exc)) from exc
    if as_json:
        typer.echo(json.dumps(info, indent=2))
        return
    cc, dc = info["color_camera"], info["depth_camera"]
    fps = f"{info['fps']:.1f} fps" if info["fps"] else "no timing"
    skew = info["skew_ms"]
    typer.echo(f"bag        {info['path']} ({info['storage']}, {_human_bytes(info['size_bytes'])})")
    typer.echo(f"layout     {info['layout']}: colour {info['color_topic']} ({info['color_messages']}), depth {info['depth_topic']} ({info['depth_messages']})")
    typer.echo(
        f"frames     {info['frames']} colour/depth pairs within {info['max_skew_ms']:.1f} ms over {info['duration_s']:.2f} s ({fps})"
        + (f"; skew median {skew['median']:.1f} ms, max {skew['max']:.1f} ms" if skew else "")
    )
    lat = info["latency_ms"]
    if lat and abs(lat["depth"] - lat["color"]) >= 0.1:
        typer.echo(f"latency    depth recorded {lat['depth'] - lat['color']:.1f} ms after colour (header stamps); paired by stamp time")
    typer.echo(f"colour     {cc['width']}x{cc['height']} fx={cc['fx']:.2f} fy={cc['fy']:.2f} cx={cc['cx']:.2f} cy={cc['cy']:.2f}")
    reg = "registered to colour" if info["registered"] else f"aligned to colour with extrinsics from {info['extrinsics']}"
    typer.echo(f"depth      {dc['width']}x{dc['height']} fx={dc['fx']:.2f} {info['depth_encoding']}, {reg}")
    unit = f"{info['depth_unit_m'] * 1000:g} mm steps" if info["depth_unit_m"] else "float metres"
    typer.echo(f"disparity  from depth ({unit}) with baseline {info['baseline_m']} m ({info['baseline']})")
    if not info["indexed"]:
        typer.secho("note       the bag has no message index; it was scanned to find the frames", fg=typer.colors.YELLOW)
    typer.echo("topics")
    for topic, t in info["topics"].items():
        typer.echo(f"  {topic}  {t['type']}  {t['messages']}")


def export(
    path: Path = typer.Argument(..., metavar="RECORDING", help="Recording directory"),
    mcap: Path = typer.Option(..., "--mcap", help="MCAP file to write (opens in Foxglove and Rerun)"),
    measurements: Optional[Path] = typer.Option(None, "--measurements", help="JSON list of measurements made on it"),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing MCAP file"),
) -> None:
    """Export a recording to MCAP with Foxglove schemas (RawImage, CameraCalibration, annotations)."""
    from device.errors import SourceError
    from device.formats.mcap import export_mcap, load_measurements

    try:
        meas = load_measurements(measurements) if measurements else []
        for warning in placement_warnings(path, meas):
            typer.secho(f"warning: {warning}", fg=typer.colors.YELLOW, err=True)
        counts = export_mcap(path, mcap, measurements=meas, overwrite=overwrite)
    except SourceError as exc:
        raise _fail(str(exc)) from exc
    topics = ", ".join(f"{t} {n}" for t, n in counts.items())
    typer.echo(f"wrote {mcap} ({_human_bytes(mcap.stat().st_size)}): {topics}")


def placement_warnings(recording: Path, measurements: list[dict]) -> list[str]:
    """Why measurements may be drawn on the wrong picture: those whose ``source`` is not this recording
    (another recording, a bag, a video, a live camera: their frame_index counts another stream's frames)
    and, of the others, those that name no frame (drawn on frame 0)."""
    unplaced, elsewhere = [], {}
    for k, m in enumerate(measurements):
        source = m.get("source")
        if isinstance(source, str) and source.strip() and not _is_recording(source, recording):
            elsewhere.setdefault(source.strip(), []).append(k)
        elif m.get("frame_index", m.get("frame")) is None:
            unplaced.append(k)

    def which(ks: list[int]) -> str:
        return ", ".join(map(str, ks[:10])) + (f" and {len(ks) - 10} more" if len(ks) > 10 else "")

    out = []
    if unplaced:
        out.append(f"{len(unplaced)} measurement(s) ({which(unplaced)}) name no frame_index: they are drawn on frame 0 "
                   "of the recording; give each its frame_index")
    for source, ks in elsewhere.items():
        out.append(f"{len(ks)} measurement(s) ({which(ks)}) were made on {source}, not on {recording}: they are drawn on this "
                   f"recording's frame of their frame_index (0 without one); pass only measurements made on replay:{recording}")
    return out


def _is_recording(source: str, recording: Path) -> bool:
    """Whether the spec ``source`` (``replay:DIR?...`` or a bare folder) names the recording folder ``recording``."""
    from cli.specs import source_spec
    from device.errors import SourceError

    try:
        spec = source_spec(source)
    except SourceError:  # a path that is no source (moved, or another machine's): not this recording
        return False
    kind, _, target = spec.partition("?")[0].partition(":")
    return kind == "replay" and bool(target) and Path(target).expanduser().resolve() == recording.resolve()
