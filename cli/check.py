"""`depthruler check`: the accuracy of lengths from a source, against a printed ChArUco board (check/run.py)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from cli import board as board_options


def check(
    ctx: typer.Context,
    source: str = typer.Option(..., "--source", help="Source spec, e.g. oak, v4l2:/dev/video0?calib=stereo.json, "
                               "video:pair.mkv?calib=stereo.yaml, sim:charuco?distance=2, or a recording folder."),
    squares: str = board_options.squares_option(),
    square_mm: float = board_options.square_mm_option(),
    marker_mm: float = board_options.marker_mm_option(),
    dictionary: str = board_options.dictionary_option(),
    board_paper: str | None = board_options.paper_option("The board printed by `calibrate --board-png OUT --board PAPER`: "
                                                         "its squares fit that paper (instead of --square-mm, --marker-mm)."),
    legacy: bool = board_options.legacy_option(),
    frames: int = typer.Option(1, "--frames", min=1, max=1000, help="Frames to check (more give the frame-to-frame spread)."),
    json_out: bool = typer.Option(False, "--json", help="Print the report as JSON."),
    out: Path | None = typer.Option(None, "--out", help="Folder for check.png (the board, pairs coloured by error, "
                                    "the numbers), check.json and pairs.csv (one row per pair measured)."),
    db: Path = typer.Option(Path("depthruler.db"), "--db", help="Service database; the check is kept in "
                            "<db stem>-checks.jsonl beside it (GET /api/checks)."),
    history: bool = typer.Option(True, "--history/--no-history", help="Keep this check in the history."),
    timeout_s: float = typer.Option(5.0, "--timeout", min=0.01, help="Seconds to wait for each frame."),
) -> None:
    """How accurate are lengths from this camera, here, today: measure the known lengths of a printed board.

    Without board options the simulator's charuco scene is checked against its own board."""
    from check.errors import CheckError
    from check.pairs_csv import write_pairs_csv
    from check.record import check_record, earlier_checks
    from check.run import check_frames
    from device import open_source
    from device.errors import SourceEnded, SourceError
    from history.checks import append_check, checks_path

    from cli.specs import source_spec

    board, _ = board_options.board_from_options(ctx, squares, square_mm, marker_mm, dictionary, board_paper, legacy)
    if not board_options.described(ctx):  # the simulator's charuco scene shows its own board, as in the doctor and the page
        from dataclasses import replace

        from check.doctor.board import source_board

        own = source_board(source_spec(source))
        board = board if own is None else replace(own, legacy=legacy)
    try:
        got = []
        with open_source(source_spec(source)) as src:
            info = src.info
            for _ in range(frames):
                try:
                    got.append(src.read(timeout_s))
                except SourceEnded:
                    break
        if not got:
            raise CheckError(f"{source} gave no frame; check the source")
        earlier = earlier_checks(checks_path(db), info, got[0]) if history else ()
        done = check_frames(got, board, earlier=earlier, picture=out is not None, title=f"depthruler check: {source}")
    except (SourceError, CheckError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from exc
    record = check_record(source, info, got[0], done.report)
    if history:
        try:
            record["history"] = str(append_check(checks_path(db), record))
        except SourceError as exc:
            typer.echo(f"warning: {exc}", err=True)
    if out is not None:
        try:
            out.mkdir(parents=True, exist_ok=True)
            (out / "check.png").write_bytes(done.png or b"")
            record["png"] = str(out / "check.png")
            record["pairs_csv"] = str(write_pairs_csv(out / "pairs.csv", source, done.result.pairs))
            (out / "check.json").write_text(json.dumps(record, indent=2) + "\n")
        except OSError as exc:
            typer.echo(f"error: cannot write the check to {out} ({exc.strerror or exc}); pass a writable --out", err=True)
            raise typer.Exit(1) from None
    if json_out:
        typer.echo(json.dumps(record))
        return
    typer.echo(_summary(record))


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
    for key in ("png", "pairs_csv", "history"):
        if key in r:
            lines.append(f"{key}: {r[key]}")
    return "\n".join(lines)
