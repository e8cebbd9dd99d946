"""`depthruler bench [NAME] [OPTIONS...]`: run the benchmarks of the :mod:`bench` package (each
``bench/bench_*.py`` has a ``main(argv)``; options after the name go to it, e.g. `depthruler bench measure --write`)."""

from __future__ import annotations

import importlib
import pkgutil

import typer

import bench as bench_package


def discover() -> dict[str, str]:
    """Benchmark name (module name without ``bench_``) -> module name, sorted by name."""
    names = sorted(m.name for m in pkgutil.iter_modules(bench_package.__path__) if m.name.startswith("bench_"))
    return {n.removeprefix("bench_"): f"bench.{n}" for n in names}


def bench(
    ctx: typer.Context,
    name: str = typer.Argument("all", metavar="NAME", help=f"benchmark to run: {', '.join(discover())}; or 'all'"),
) -> None:
    """Run the benchmarks and print their results; options after NAME go to the benchmark
    (`depthruler bench measure --help` lists them; `--write` records the figures in bench/RESULTS.md)."""
    found = discover()
    if name != "all" and name not in found:
        raise typer.BadParameter(f"unknown benchmark {name!r}; choose one of: all, {', '.join(found)}")
    if name == "all" and ctx.args:
        raise typer.BadParameter(f"options {' '.join(ctx.args)} need one benchmark name; choose one of: {', '.join(found)}")
    for key, module_name in found.items():
        if name not in ("all", key):
            continue
        typer.echo(f"## {key} ({module_name})")
        try:
            importlib.import_module(module_name).main(list(ctx.args))
        except ModuleNotFoundError as exc:  # the benches' own dependencies are an extra
            if exc.name and exc.name.split(".")[0] in ("bench",):
                raise
            typer.echo(f"depthruler: bench {key} needs {exc.name!r}: pip install 'depthruler[bench]'", err=True)
            raise typer.Exit(2) from None


# Options after NAME belong to the benchmark, not to this command.
bench.context_settings = {"allow_extra_args": True, "ignore_unknown_options": True}
