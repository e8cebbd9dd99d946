"""`depthruler check`: the accuracy of lengths from a source, against a printed ChArUco board (check/run.py)."""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone
from pathlib import Path

import typer


def check(
    source: str = typer.Option(..., "--source", help="Source spec, e.g. oak, v4l2:/dev/video0?calib=stereo.json, "
                               "video:pair.mkv?calib=stereo.yaml or sim:charuco?distance=2."),
    squares: str = typer.Option("11x8", "--squares", help="ChArUco squares across x down (as printed by calibrate)."),
    square_mm: float = typer.Option(30.0, "--square-mm", help="Printed square side in mm (measure it with a ruler)."),
    marker_mm: float = typer.Option(22.0, "--marker-mm", help="Printed marker side in mm."),
    dictionary: str = typer.Option("DICT_5X5_100", "--dictionary", help="ArUco dictionary of the board."),
    frames: int = typer.Option(1, "--frames", min=1, max=1000, help="Frames to check (more give the frame-to-frame spread)."),
    json_out: bool = typer.Option(False, "--json", help="Print the report as JSON."),
    out: Path | None = typer.Option(None, "--out", help="Folder for check.png (the board, pairs coloured by error, "
                                    "the numbers) and check.json."),
    db: Path = typer.Option(Path("depthruler.db"), "--db", help="Service database; the check is kept in "
                            "<db stem>-checks.jsonl beside it (GET /api/checks)."),
    history: bool = typer.Option(True, "--history/--no-history", help="Keep this check in the history."),
    timeout_s: float = typer.Option(5.0, "--timeout", help="Seconds to wait for each frame."),
) -> None:
    """How accurate are lengths from this camera, here, today: measure the known lengths of a printed board."""
    from device import open_source
    from device.calibration.stereo import BoardSpec
    from history.checks import append_check, calibration_of, camera_of, checks_path, read_checks
    from cli.devices import parse_squares
    from device.errors import SourceEnded, SourceError

    from check.run import CheckError, report, run_check
    from check.plot import write_check_png

    sx, sy = parse_squares(squares)
    try:
        board = BoardSpec(sx, sy, square_mm / 1000.0, marker_mm / 1000.0, dictionary)
        got = []
        with open_source(source) as src:
            info = src.info
            for _ in range(frames):
                try:
                    got.append(src.read(timeout_s))
                except SourceEnded:
                    break
        if not got:
            raise CheckError(f"{source} gave no frame; check the source")
        result = run_check(got, board)
        calib, calib_hash = calibration_of(source)
        camera, camera_hash = camera_of(got[0])
        # earlier checks of this camera with this calibration: does the bias change with distance?
        earlier = [r for r in read_checks(checks_path(db), serial=info.serial)
                   if r.get("camera_sha256") == camera_hash and r.get("kind") == info.kind] if history else []
        rep = report(result, earlier)
    except (SourceError, CheckError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from exc
    record = {
        "time": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "source": source,
        "kind": info.kind,
        "serial": info.serial,
        "calibration": calib,
        "calibration_sha256": calib_hash,
        "camera": camera,
        "camera_sha256": camera_hash,
        **rep,
    }
    record = _finite(record)
    if history:
        try:
            record["history"] = str(append_check(checks_path(db), record))
        except SourceError as exc:
            typer.echo(f"warning: {exc}", err=True)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        frame = got[result.views[0].frame]
        record["png"] = str(write_check_png(out / "check.png", frame, result, rep, title=f"depthruler check: {source}"))
        (out / "check.json").write_text(json.dumps(record, indent=2) + "\n")
    if json_out:
        typer.echo(json.dumps(record))
        return
    typer.echo(_summary(record))


def _finite(x):
    """NaN and inf become None (strict JSON)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def _summary(r: dict) -> str:
    f = r["figures"]

    def n(x, fmt="{:.1f}"):
        return "-" if x is None else fmt.format(x)

    margin = None if f["bias_se_pct"] is None else 1.96 * f["bias_se_pct"]
    lines = [
        f"check {r['status'].upper()}: {r['source']} (serial {r['serial']}), board {f['board']['squares']} x "
        f"{f['board']['square_mm']:g} mm at {n(f['distance_m'], '{:.2f}')} m, tilt {n(f['tilt_deg'])} deg",
        f"  {f['pairs']} pairs on {f['frames_with_board']}/{f['frames']} frames: mean A {f['mean_accuracy']:.2f}, "
        f"median A {f['median_accuracy']:.2f}, bias {f['bias_pct']:+.2f} % (±{n(margin, '{:.2f}')}), "
        f"spread {f['spread_pct']:.2f} %",
        f"  good {100 * f['good_share']:.0f} %, truth inside the 95 % interval {100 * f['interval_coverage']:.0f} %, "
        f"fill rate {n(None if f['fill_rate'] is None else 100 * f['fill_rate'], '{:.0f}')} %, "
        f"plane-fit RMS {n(f['plane_rms_mm'])} mm (robust {n(f['plane_noise_mm'])} mm), "
        f"stereo depth vs pose {n(f['depth_vs_pose_pct'], '{:+.2f}')} %",
    ]
    if f["frame_spread_pct"] is not None:
        lines.append(f"  frame-to-frame spread {f['frame_spread_pct']:.2f} % ({f['frame_spread_mm']:.2f} mm)")
    lines.append("  per length: " + "; ".join(f"{k} A {v['mean_accuracy']:.2f} bias {v['bias_pct']:+.2f} %"
                                             for k, v in f["per_length"].items()))
    for x in r["findings"]:
        lines.append(f"- [{x['severity']}] measured: {x['measured']}")
        if x["cause"]:
            lines.append(f"    likely cause: {x['cause']}")
        if x["action"]:
            lines.append(f"    do: {x['action']}")
    if not r["findings"]:
        lines.append("- nothing to act on")
    for key in ("png", "history"):
        if key in r:
            lines.append(f"{key}: {r[key]}")
    return "\n".join(lines)
