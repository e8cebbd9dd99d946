"""`depthruler bench [NAME] [OPTIONS...]`: run the benchmark scripts in bench/ (each bench_*.py has a
``main(argv)``; options after the name go to the script, e.g. `depthruler bench measure --write`)."""

from __future__ import annotations

import sys

import typer

BENCH_DIR_NAME = "bench"


def _bench_dir():
    from pathlib import Path

    return Path(__file__).resolve().parents[1] / BENCH_DIR_NAME


def discover() -> dict[str, object]:
    """Benchmark name (file name without ``bench_`` and ``.py``) -> path, sorted by name."""
    return {p.stem.removeprefix("bench_"): p for p in sorted(_bench_dir().glob("bench_*.py"))}


def load(name: str, path):
    """Import the bench script at ``path`` as a module (bench scripts share bench/results_file.py,
    as they do when run as `python bench/bench_x.py`)."""
    import importlib.util

    if str(_bench_dir()) not in sys.path:
        sys.path.insert(0, str(_bench_dir()))
    spec = importlib.util.spec_from_file_location(f"depthruler_bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bench(
    ctx: typer.Context,
    name: str = typer.Argument("all", help="benchmark to run (e.g. 'measure'), or 'all'"),
) -> None:
    """Run the benchmarks in bench/ and print their results; options after NAME go to the script
    (`python bench/bench_measure.py --help` lists them; `--write` records the figures in bench/RESULTS.md)."""
    found = discover()
    if not found:
        raise typer.BadParameter(f"no bench_*.py scripts in {_bench_dir()}")
    if name != "all" and name not in found:
        raise typer.BadParameter(f"unknown benchmark {name!r}; choose one of: all, {', '.join(found)}")
    if name == "all" and ctx.args:
        raise typer.BadParameter(f"options {' '.join(ctx.args)} need one benchmark name; choose one of: {', '.join(found)}")
    for key, path in found.items():
        if name not in ("all", key):
            continue
        typer.echo(f"## {key} ({path.name})")
        try:
            module = load(key, path)
            if not hasattr(module, "main"):
                raise typer.BadParameter(f"{path} has no main(); every bench script needs one")
            module.main(list(ctx.args))
        except ModuleNotFoundError as exc:  # the benches' own dependencies are an extra
            typer.echo(f"depthruler: bench {key} needs {exc.name!r}: pip install 'depthruler[bench]'", err=True)
            raise typer.Exit(2) from None


# Options after NAME belong to the script, not to this command.
bench.context_settings = {"allow_extra_args": True, "ignore_unknown_options": True}
