"""`depthruler devices` and `depthruler calibrate`. Heavy imports stay inside the commands."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import typer

from cli import board as board_options


def devices(json_out: bool = typer.Option(False, "--json", help="Print machine-readable JSON.")) -> None:
    """List attached cameras: OAK devices (DepthAI), V4L2 nodes and USB cameras."""
    from device.discovery import list_devices

    found = list_devices()
    if json_out:
        typer.echo(json.dumps({"devices": [asdict(d) for d in found], "count": len(found)}, indent=2))
        return
    if not found:
        typer.echo("no cameras found (no OAK over DepthAI, no /dev/video* nodes, no USB video devices).")
        typer.echo("Plug in an OAK or a UVC stereo camera, or try the simulated rig:")
        typer.echo("  depthruler serve --source sim")
        return
    for d in found:
        size = f" {d.width}x{d.height}" if d.width else ""
        state = f" [{d.state}]" if d.state else ""
        spec = d.extra.get("spec", "")
        usb_id = d.extra.get("usb_id", "")
        details = "  ".join(x for x in (d.serial, usb_id, f"spec: {spec}" if spec else "") if x)
        typer.echo(f"{d.kind:5} {d.name}{size}{state}  {details}".rstrip())
        if d.extra.get("fix"):
            typer.echo(f"      no permission to open it; fix:\n      {d.extra['fix']}")


def calibrate(
    ctx: typer.Context,
    images: Path | None = typer.Option(None, "--images", help="Folder of view pairs: left/ + right/, "
                                       "NAME_left/NAME_right, or side-by-side images with --side-by-side."),
    live: str | None = typer.Option(None, "--live", help="Capture from a stereo pair or video, e.g. "
                                    "v4l2:/dev/video0 or video:board.mkv?layout=side-by-side."),
    out: Path = typer.Option(Path("calibration.json"), "--out", "-o", help="Calibration file to write."),
    fmt: str = typer.Option("json", "--format", help="json (depthruler's own), opencv-yaml, opencv-xml, or ros "
                            "(writes OUT_left.yaml + OUT_right.yaml camera_info files)."),
    board_png: Path | None = typer.Option(None, "--board-png", help="Only write the printable board PNG here "
                                          "(print at 100 %, then measure a square) and exit."),
    dpi: float = typer.Option(300.0, "--dpi", help="Resolution of --board-png."),
    squares: str = board_options.squares_option(),
    square_mm: float = board_options.square_mm_option(),
    marker_mm: float = board_options.marker_mm_option(),
    dictionary: str = board_options.dictionary_option(),
    paper: str | None = board_options.paper_option("Size the squares to print on this paper (instead of --square-mm, "
                                                   "--marker-mm); `check --board PAPER` checks against it."),
    side_by_side: bool = typer.Option(False, "--side-by-side", help="Each image holds left | right halves."),
    legacy: bool = board_options.legacy_option(),
    views: int = typer.Option(20, "--views", help="Live capture: how many distinct board views to collect."),
    save_views: Path | None = typer.Option(None, "--save-views", help="Live capture: also save the pairs here."),
) -> None:
    """Calibrate a stereo pair from ChArUco board views and write the calibration (or print the board)."""
    from device.calibration.board import write_board_png
    from device.calibration.solve import calibrate_stereo, load_image_pairs
    from device.calibration.files import FORMATS, write
    from device.errors import SourceError

    if fmt not in FORMATS:
        raise typer.BadParameter(f"{fmt!r} is not one of {', '.join(FORMATS)}", param_hint="--format")
    board, margin_mm = board_options.board_from_options(ctx, squares, square_mm, marker_mm, dictionary, paper, legacy)
    try:
        if board_png is not None:
            path, w_mm, h_mm = write_board_png(board, board_png, dpi=dpi, **({} if margin_mm is None else {"margin_mm": margin_mm}))
            sq = board.square_m * 1000
            then = (f"if it is {sq:g} mm, pass --board {paper} to calibrate and check; if not, pass what you measure as "
                    "--square-mm and --marker-mm") if paper else "pass that as --square-mm"
            typer.echo(f"wrote {path}: {board.squares_x}x{board.squares_y} squares of {sq:g} mm, markers {board.marker_m * 1000:g} mm, "
                       f"{dictionary}; sheet {w_mm:.1f} x {h_mm:.1f} mm at {dpi:g} dpi{f', fits {paper}' if paper else ''}. "
                       f"Print at 100 % (actual size), glue it flat and measure a square: {then}.")
            _warn_unless_it_fits(w_mm, h_mm)
            return
        if (images is None) == (live is None):
            raise typer.BadParameter("give exactly one of --images DIR or --live SPEC (or --board-png OUT)")
        if images is not None:
            pairs = load_image_pairs(images, side_by_side=side_by_side)
            typer.echo(f"{len(pairs)} view pairs from {images}")
        elif live is not None:
            from device.calibration.capture import capture_views

            pairs = capture_views(_grabber(live), board, views, save_to=save_views, progress=typer.echo)
        calib = calibrate_stereo(pairs, board, progress=typer.echo)
        written = write(calib, out, fmt)
    except SourceError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from exc
    used = sum(v.used for v in calib.views)
    typer.echo(f"wrote {', '.join(map(str, written))}: {used}/{len(calib.views)} views used, RMS {calib.rms:.3f} px, "
               f"baseline {calib.baseline_m * 1000:.2f} mm")


def _warn_unless_it_fits(width_mm: float, height_mm: float) -> None:
    """Warn when a board sheet prints on neither A4 nor US Letter at 100 % (a printer would shrink it)."""
    from check.boards import papers_that_fit

    if not papers_that_fit(width_mm, height_mm):
        typer.secho(f"warning: a {width_mm:.0f} x {height_mm:.0f} mm sheet fits neither A4 nor US Letter at 100 %; "
                    "pass --board a4 or --board letter for the largest board that does (or fewer or smaller squares)",
                    fg=typer.colors.YELLOW, err=True)  # fmt: skip


def _grabber(spec: str):
    """The stereo grabber of a --live spec: a V4L2 pair or a stereo video."""
    from device.base import SourceSpec
    from device.errors import SourceError

    parsed = SourceSpec.parse(spec)
    if parsed.kind == "v4l2":
        from device.sources.stereo_pair import V4L2Grabber, config_from_spec

        return V4L2Grabber(config_from_spec(parsed))
    if parsed.kind == "video":
        from device.sources.video import VideoGrabber, config_from_spec as video_config

        return VideoGrabber(video_config(parsed))
    raise SourceError(f"--live takes a v4l2: or video: spec, not {parsed.kind!r}")
