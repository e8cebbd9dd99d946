"""The `depthruler` command line: one Typer app that assembles the command modules of :mod:`cli`."""

from __future__ import annotations

import os
import sys
from typing import Any

import typer
from typer.core import TyperGroup

# DepthAI prints a USB banner on import in containers; keep CLI output clean.
os.environ.setdefault("DEPTHAI_LEVEL", "error")



class OneLineErrors(TyperGroup):
    """The root command: a usage error (a bad option value, a missing option) is one line on stderr,
    ``depthruler CMD: MESSAGE (see depthruler CMD --help)``, where typer draws a panel that wraps a
    long message over several lines. Exit codes stay click's (2 for usage errors)."""

    def main(self, args: Any = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:  # fmt: skip
        from typer import rich_utils
        from typer._click.exceptions import ClickException, NoArgsIsHelpError, UsageError
        from typer.exceptions import Abort

        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except NoArgsIsHelpError as exc:  # the help itself, as typer shows it
            rich_utils.rich_format_error(exc)
            sys.exit(exc.exit_code)
        except UsageError as exc:
            where = exc.ctx.command_path if exc.ctx is not None else (prog_name or "depthruler")
            typer.echo(f"{where}: {' '.join(exc.format_message().split())} (see {where} --help)", err=True)
            sys.exit(exc.exit_code)
        except ClickException as exc:
            typer.echo(f"depthruler: {' '.join(exc.format_message().split())}", err=True)
            sys.exit(exc.exit_code)
        except Abort:
            typer.echo("Aborted!", err=True)
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    cls=OneLineErrors,
    name="depthruler",
    help="Measure real objects with depth cameras: click two points, get a robust 3D length.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

from cli import batch as batch_cmd  # noqa: E402 — after the DepthAI setting
from cli import bench as bench_cmd  # noqa: E402
from cli import check as check_cmd  # noqa: E402
from cli import data as data_cmd  # noqa: E402
from cli import devices as devices_cmd  # noqa: E402
from cli import doctor as doctor_cmd  # noqa: E402
from cli import eval as eval_cmd  # noqa: E402
from cli import recording as recording_cmd  # noqa: E402
from cli import serve as serve_cmd  # noqa: E402

# Each command module keeps its heavy imports inside the command body, so `--help` stays fast.
for name, command in {
    "devices": devices_cmd.devices,
    "doctor": doctor_cmd.doctor,
    "serve": serve_cmd.serve,
    "measure": serve_cmd.measure,
    "record": recording_cmd.record,
    "replay": recording_cmd.replay,
    "export": recording_cmd.export,
    "calibrate": devices_cmd.calibrate,
    "check": check_cmd.check,
    "bench": bench_cmd.bench,
}.items():
    help_class = {"cls": serve_cmd.DefaultsInHelp} if command in (serve_cmd.serve, serve_cmd.measure) else {}
    app.command(name, context_settings=getattr(command, "context_settings", None), **help_class)(command)
app.add_typer(eval_cmd.app, name="eval")
app.add_typer(batch_cmd.app, name="batch")
app.add_typer(data_cmd.app, name="data")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
