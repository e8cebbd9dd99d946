"""The `depthruler` command line. Each command lives in the module of the part it drives;
command modules import their heavy dependencies inside the command body so `--help` stays fast."""

from __future__ import annotations

import importlib
import os

import typer

# DepthAI prints a USB banner on import in containers; keep CLI output clean.
os.environ.setdefault("DEPTHAI_LEVEL", "error")

app = typer.Typer(
    name="depthruler",
    help="Measure real objects with depth cameras: click two points, get a robust 3D length.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# command name -> "module:attribute"; the attribute is a function (a command; its optional
# ``context_settings`` attribute goes to click) or a typer.Typer (a group).
COMMANDS: dict[str, str] = {
    "devices": "device.cli:devices",
    "serve": "service.cli_serve:serve",
    "measure": "service.cli_serve:measure",
    "record": "device.recording_cli:record",
    "replay": "device.recording_cli:replay",
    "export": "device.recording_cli:export",
    "calibrate": "device.cli:calibrate",
    "eval": "evaluation.cli:app",
    "check": "evaluation.check_cli:check",
    "batch": "evaluation.batch_cli:app",
    "bench": "service.bench_cli:bench",
}


def _register() -> None:
    for name, target in COMMANDS.items():
        module_name, _, attr = target.partition(":")
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:  # that part is not built yet
                continue
            raise
        obj = getattr(module, attr)
        if isinstance(obj, typer.Typer):
            app.add_typer(obj, name=name)
        else:
            app.command(name, context_settings=getattr(obj, "context_settings", None))(obj)


_register()


def main() -> None:
    app()


if __name__ == "__main__":
    main()
