"""`depthruler data fetch|check`: the Middlebury scenes the evaluation and the tests use."""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(help="The real stereo scenes (Middlebury 2014) the evaluation and the tests use: fetch and check them.",
                  no_args_is_help=True)


@app.command("fetch")
def fetch_command(
    dest: Path = typer.Option(None, "--dest", help="Folder for the scenes; left out, the folder the tests and `eval middlebury` read."),
    from_dir: Path = typer.Option(None, "--from", help="A folder that already holds MiddEval3-data-Q.zip and MiddEval3-GT0-Q.zip (no download)."),
    url: str = typer.Option(None, "--url", help="Base URL of the two archives; left out, vision.middlebury.edu."),
) -> None:
    """Download the eight scenes, check every file's SHA-256, and put them where the tests find them."""
    from evaluation.middlebury_data import BASE_URL, DataError, fetch

    try:
        where = fetch(dest, base_url=url or BASE_URL, archives_dir=from_dir, progress=typer.echo)
    except DataError as exc:
        typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
        raise typer.Exit(1) from None
    typer.echo(f"Middlebury scenes ready in {where}")


@app.command("check")
def check_command(
    data: Path = typer.Option(None, "--data", help="Folder of the scenes; left out, the folder the tests read."),
) -> None:
    """Say whether every file of the eight scenes is present and matches its recorded SHA-256."""
    from evaluation.middlebury_data import FETCH_COMMAND, default_data_dir, verify

    folder = data or default_data_dir()
    bad = verify(folder)
    if bad:
        typer.echo(f"{len(bad)} file(s) missing or changed in {folder} (first: {bad[0]}); run `{FETCH_COMMAND}`")
        raise typer.Exit(1)
    typer.echo(f"all 40 files of the 8 scenes in {folder} match their checksums")
