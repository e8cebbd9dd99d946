"""`depthruler doctor`: the first command to run when a camera is plugged in (the checks: check/doctor/)."""

from __future__ import annotations

import json

import typer

from cli import board as board_options

def doctor(
    ctx: typer.Context,
    source: str | None = typer.Option(None, "--source", help="Source spec to check, e.g. oak, sim, replay:DIR, "
                                      "video:pair.mkv?layout=side-by-side&calib=stereo.yaml; left out, the attached camera."),
    window_s: float = typer.Option(10.0, "--window", min=0.1, max=600.0, help="Seconds to read frames for (fps, timestamps)."),
    json_out: bool = typer.Option(False, "--json", help="Print the findings as JSON."),
    squares: str = board_options.squares_option(),
    square_mm: float = board_options.square_mm_option(),
    marker_mm: float = board_options.marker_mm_option(),
    dictionary: str = board_options.dictionary_option(),
    board_paper: str | None = board_options.paper_option("The board printed by `calibrate --board-png OUT --board PAPER`."),
) -> None:
    """Check a camera end to end: USB, versions, frames and fps, timestamps, depth fill, calibration, and a board if in view.

    Each check prints pass / warn / fail / skip and what to do; the exit code is 1 when one fails."""
    from check.doctor import NO_CAMERA, attached_source, run_doctor

    from cli.specs import source_spec

    board = None
    if board_options.described(ctx):  # otherwise the doctor looks for the source's own board, or the default print
        board, _ = board_options.board_from_options(ctx, squares, square_mm, marker_mm, dictionary, board_paper)
    if source is None:
        source = attached_source()
        if source is None:
            if json_out:
                typer.echo(json.dumps({"source": None, "status": "fail", "findings": [], "message": NO_CAMERA}))
            else:
                typer.echo(NO_CAMERA)
            raise typer.Exit(1)
    progress = (lambda _: None) if json_out else (lambda m: typer.echo(f"... {m}", err=True))
    report = run_doctor(source_spec(source), window_s=window_s, board=board, progress=progress)
    if json_out:
        typer.echo(json.dumps(report.to_dict(), allow_nan=False, default=_plain))
    else:
        typer.echo(summary(report))
    if report.status == "fail":
        raise typer.Exit(1)


def _plain(x):  # numpy scalars in figures
    return x.item() if hasattr(x, "item") else str(x)


def summary(report) -> str:
    """The findings as lines: the report's one-line note first when it has one (no camera attached), a
    header, then ``[status] check: measured`` and, under a finding that is not a pass, ``fix: ...``."""
    counts = {s: sum(f.status == s for f in report.findings) for s in ("pass", "warn", "fail", "skip")}
    lines = [report.note] if report.note else []
    lines += [f"doctor {report.status.upper()}: {report.source} ({', '.join(f'{n} {s}' for s, n in counts.items())})"]
    for f in report.findings:
        lines.append(f"[{f.status}] {f.check}: {f.measured}")
        if f.fix and f.status != "pass":
            lines.append(f"       fix: {f.fix}")
    return "\n".join(lines)
