"""`depthruler batch TASKS --out RESULTS.parquet`, `depthruler batch diff A B` and `depthruler batch export`."""

from __future__ import annotations

import json
import os
from pathlib import Path

import typer
from typer.core import TyperGroup


class _RunByDefault(TyperGroup):
    """`depthruler batch TASKS ...` means `depthruler batch run TASKS ...`; `diff` and `export` are the others."""

    def parse_args(self, ctx, args):  # type: ignore[no-untyped-def]
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


app = typer.Typer(
    cls=_RunByDefault,
    help="Re-measure archives of recordings (or the service's history) on this machine or a Ray cluster; compare two runs; export one as CSV. "
    "`depthruler batch TASKS --out RESULTS.parquet` is short for `depthruler batch run TASKS --out RESULTS.parquet`.",
    no_args_is_help=True,
)


def _fail(message: str) -> typer.Exit:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    return typer.Exit(code=1)


def _progress():
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
    from rich.text import Text

    class Rate(ProgressColumn):
        def render(self, task):  # type: ignore[no-untyped-def]
            return Text(f"{task.speed:.1f} tasks/s" if task.speed else "- tasks/s")

    return Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), Rate(), TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn()
    )


@app.command("run")
def run_command(
    tasks_file: str = typer.Argument(None, metavar="TASKS", help="CSV, JSONL or Parquet table of tasks (a path or a URL such as s3://bucket/tasks.csv): source, frame, p1_x, p1_y, p2_x, p2_y [, method, ...]; shapes: kind (height, path, area, box) and points as JSON [[x, y], ...] [, on] (docs/batch.md)."),
    out: Path = typer.Option(..., "--out", "-o", help="Results file (Parquet)."),
    from_history: Path = typer.Option(None, "--from-history", help="Re-measure every measurement (segments and shapes) in this service history database instead of TASKS."),
    workers: int = typer.Option(os.cpu_count() or 1, "--workers", "-j", min=1, help="Worker processes (1 = in this process; the default is one per CPU). With --ray local: the CPUs Ray may use."),
    ray: str = typer.Option(None, "--ray", help="Run on Ray: 'auto' (the cluster running here or at RAY_ADDRESS), 'local' (start one here) or an address (HOST:6379, ray://HOST:10001)."),
    set_: list[str] = typer.Option([], "--set", help="Default measurement option KEY=VALUE for tasks that do not set it (repeatable), e.g. --set method=paper."),
    resume: bool = typer.Option(False, "--resume", help="Finish an interrupted run: keep the rows already written, run only the others."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Discard an existing results file (and any interrupted run) first."),
) -> None:
    """Measure every task and write one row per task (bad rows and failures as error rows) to RESULTS.parquet."""
    from batch.errors import BatchError
    from batch.executors import make_executor
    from batch.history import history_tasks
    from batch.run import close_readers, default_options, run_batch
    from batch.tasks import read_tasks

    if (tasks_file is None) == (from_history is None):
        raise _fail("give a TASKS table or --from-history DB (one of them)")
    try:
        defaults = default_options(set_)
        tasks = history_tasks(from_history) if from_history else read_tasks(tasks_file)
        executor = make_executor(workers, ray)
    except BatchError as exc:  # a bad table, option or executor: the message says what to change
        raise _fail(str(exc)) from None
    errors = 0
    progress = _progress()  # shown once the results store is open: a bad --out is refused before it
    bar = progress.add_task("measuring", total=len(tasks))

    def started(todo: int, skipped: int) -> None:
        progress.start()
        progress.update(bar, total=todo)
        progress.console.print(f"{len(tasks)} tasks, {skipped} already done; running {todo} {executor.describe()}", soft_wrap=True)

    def group_done(result) -> None:  # noqa: ANN001 — a batch.rows.GroupResult
        nonlocal errors
        errors += result.errors
        progress.advance(bar, result.rows)

    try:
        summary = run_batch(tasks, out, executor, defaults=defaults, resume=resume, overwrite=overwrite, on_start=started, on_group=group_done)
    except BatchError as exc:  # unwritable output, a full disk, a changed table: what was kept and what to do
        progress.stop()
        raise _fail(str(exc)) from None
    finally:
        progress.stop()
        executor.close()
        close_readers()
    rate = summary["measured"] / summary["wall_s"] if summary["wall_s"] > 0 else float("nan")
    typer.echo(
        f"{summary['measured']} tasks measured ({errors} error rows) in {summary['wall_s']:.1f} s ({rate:.1f} tasks/s), "
        f"{summary['skipped']} kept from before; {summary['rows']} rows in {out}"
    )
    typer.echo(error_summary(summary["errors"]))


def error_summary(counts: dict) -> str:
    """One line: the results file's error rows by type, and the fields to blame."""
    types, fields = counts["type"], counts["field"]
    if not types:
        return "no error rows"
    by_type = ", ".join(f"{k} {v}" for k, v in types.most_common())
    by_field = ", ".join(f"{k} {v}" for k, v in fields.most_common())
    return f"error rows by type: {by_type}" + (f"; by field: {by_field}" if by_field else "")


@app.command("export")
def export_command(
    results: Path = typer.Argument(..., metavar="RESULTS", help="Results file written by `depthruler batch --out` (Parquet)."),
    csv_out: Path = typer.Option(..., "--csv", help="CSV file to write (formula-like text cells are neutralised)."),
    samples: bool = typer.Option(False, "--samples", help="Also write the per-sample columns samples_px and support."),
) -> None:
    """Write a results file as CSV for spreadsheets: one row per task, list cells as JSON."""
    from batch.errors import BatchError
    from batch.export import export_csv

    try:
        n = export_csv(results, csv_out, samples=samples)
    except BatchError as exc:
        raise _fail(str(exc)) from None
    typer.echo(f"wrote {n} rows to {csv_out}")


@app.command("diff")
def diff_command(
    a: Path = typer.Argument(..., metavar="A", help="Results of the reference run (Parquet)."),
    b: Path = typer.Argument(..., metavar="B", help="Results of the run to compare (Parquet)."),
    top: int = typer.Option(10, "--top", min=0, help="List this many of the largest moves."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """What changed from A to B: answers (distances, shape values, box dimensions) that moved by more than their uncertainty, changed verdicts."""
    from batch.diff import diff_results
    from batch.errors import BatchError

    try:
        d = diff_results(a, b, top)
    except BatchError as exc:
        raise _fail(str(exc)) from None
    if as_json:
        typer.echo(json.dumps(d, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    con = Console()
    con.print(f"A {a}: {d['rows_a']} rows; B {b}: {d['rows_b']} rows; matched {d['matched']} (only in A {d['only_in_a']}, only in B {d['only_in_b']})")
    for side in ("a", "b"):
        run = d["runs"][side]
        opts = ", ".join(f"{k}={v}" for k, v in sorted(run["options"].items())) or "defaults"
        con.print(f"{side.upper()} options: {opts}" + (f" (depthruler {run['version']})" if run["version"] else ""))
    con.print("status: " + ", ".join(f"{k} {v}" for k, v in sorted(d["status"].items())))
    con.print(
        f"answers compared {d['compared']}: {d['unchanged_exactly']} identical, "
        f"{d['moved_beyond_uncertainty']} moved by more than their uncertainty (a box: any of its three dimensions)"
    )
    for kind, c in d["changes_by_kind"].items():
        scale, unit = (1e4, "cm²") if c["unit"] == "m2" else (1e3, "mm")
        con.print(f"{kind}: {c['answers']} answer(s), |change| median {c['median_abs_change'] * scale:.2f} {unit}, max {c['max_abs_change'] * scale:.2f} {unit}")
    for col in d["verdict_columns"]:
        changes = d["verdict_changes"].get(col, {})
        con.print(f"{col} changed: " + (", ".join(f"{k} ({v})" for k, v in sorted(changes.items())) or "none"))
    if d["largest_moves"]:
        t = Table(title="largest moves")
        for c in ("task A", "source", "frame", "kind", "answer", "A", "B", "change", "u A", "u B"):
            t.add_column(c)
        for m in d["largest_moves"]:
            t.add_row(
                str(m["task_a"]), m["source"], str(m["frame"]), m["kind"], m["answer"], f"{m['a']:.4f}", f"{m['b']:.4f}",
                f"{m['delta']:+.4f}", f"{m['uncertainty_a']:.4f}", f"{m['uncertainty_b']:.4f}",
            )  # fmt: skip
        con.print(t)
