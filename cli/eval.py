"""`depthruler eval sim|middlebury|wall|rooms|gaps|...`: the accuracy reports (Markdown + PNG plots + results.json)."""

from __future__ import annotations

import time
from pathlib import Path

import typer


RAY_HELP = "Run on Ray: 'auto' (the cluster running here or at RAY_ADDRESS), 'local' (start one here) or an address (HOST:6379, ray://HOST:10001)."

app = typer.Typer(
    help="Measure depthruler's accuracy: the paper's study on the simulated rig, and real stereo (Middlebury).",
    no_args_is_help=True,
)


def _progress():
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        transient=False,
    )


@app.command("sim")
def sim_command(
    out: Path = typer.Option(..., "--out", help="Output folder for report.md, results.json, measurements.csv and plots."),
    measurements: int = typer.Option(1800, "--measurements", "-n", min=1, help="Non-gap measurements, spread evenly over 84 (measurement, distance, lighting) cells: the paper's set of seven (3 poster widths, 3 lengths, a person's height)."),
    seed: int = typer.Option(0, "--seed", help="Base seed; each measurement's scene, sensor noise and clicks derive from it."),
    gap_fraction: float = typer.Option(0.1, "--gap-fraction", min=0.0, max=1.0, help="Extra gap-scene measurements, as a fraction of --measurements."),
    workers: int = typer.Option(2, "--workers", "-j", min=1, help="Worker processes (1 = in this process); with --ray local, Ray's CPUs."),
    ray: str = typer.Option(None, "--ray", help=RAY_HELP),
    quantization: float | None = typer.Option(None, "--quantization", show_default="the profile's", help="Disparity step of the simulated sensor in px."),
    profile: str = typer.Option("stress", "--profile", help="Simulator profile: 'stress' (harsh end points) or 'paper' (the paper's tablet; see sim/sensor.py)."),
) -> None:
    """The paper's protocol on the simulated rig: its 7 measurements x 4 distances x 3 lightings, 4 methods."""
    from batch.executors import make_executor
    from evaluation.sim_report import write_sim_report
    from evaluation.sim_study import plan_sim, run_sim, sim_protocol, summarize_sim
    from batch.errors import BatchError
    from evaluation.report import EvalError

    try:
        jobs = plan_sim(measurements, seed, gap_fraction, quantization, profile)
        executor = make_executor(workers, ray)
    except (EvalError, BatchError) as exc:
        raise typer.BadParameter(str(exc)) from exc
    t0 = time.perf_counter()
    with _progress() as progress, executor:
        task = progress.add_task("simulating + measuring", total=len(jobs))
        records = run_sim(jobs, on_result=lambda _r: progress.advance(task), executor=executor)
    protocol = sim_protocol(measurements, seed, workers, gap_fraction, quantization, profile)
    protocol["wall_time_s"] = time.perf_counter() - t0
    results = summarize_sim(records, protocol)
    write_sim_report(out, results, records)
    _print_summary(results["methods"], f"{out / 'report.md'}", protocol["wall_time_s"], results["gap"])


@app.command("shapes")
def shapes_command(
    out: Path = typer.Option(..., "--out", help="Output folder for report.md, shapes.csv, results.json and plots."),
    boxes: int = typer.Option(200, "--boxes", "-n", min=1, help="Box cases per profile (random sizes, yaws, 0.6-3 m; some cut by the border or beside another box)."),
    panels: int = typer.Option(50, "--panels", min=0, help="Framed-panel area cases per profile."),
    seed: int = typer.Option(0, "--seed", help="First seed; case i of each profile uses seed + i."),
    profile: list[str] = typer.Option(None, "--profile", show_default="stress and paper", help="Simulator profile (repeatable)."),
    width: int = typer.Option(1280, "--width", min=64, help="Image width (px)."),
    height: int = typer.Option(720, "--height", min=36, help="Image height (px)."),
    workers: int = typer.Option(2, "--workers", "-j", min=1, help="Worker processes (1 = in this process)."),
) -> None:
    """Boxes (L x W x H), heights and panel areas on the simulated rig against their truth (evaluation/shapes.py)."""
    from evaluation.shapes import PROFILES, checks, plan, run, summarize
    from evaluation.shapes_report import write_shapes_report
    from sim.sensor import get_profile

    profiles = tuple(profile) if profile else PROFILES
    for p in profiles:
        try:
            get_profile(p)
        except Exception as exc:  # noqa: BLE001 — SensorError: name the choices
            raise typer.BadParameter(str(exc), param_hint="--profile") from None
    jobs = plan(boxes, panels, seed, profiles, width, height)
    t0 = time.perf_counter()
    with _progress() as progress:
        task = progress.add_task("simulating + measuring shapes", total=len(jobs))
        records = run(jobs, workers, on_result=lambda _r: progress.advance(task))
    protocol = {"boxes": boxes, "panels": panels, "seed": seed, "profiles": list(profiles), "width": width, "height": height,
                "workers": workers, "wall_time_s": time.perf_counter() - t0}
    paths = write_shapes_report(out, records, protocol)
    for prof, name, value, limit, met in checks(summarize(records)):
        print(f"{prof}: {name}: {'–' if value is None else f'{value:.3f}'} (target {limit}){'' if met else '  NOT MET'}")
    print(f"report: {paths['report']}")


@app.command("frames")
def frames_command(
    out: Path = typer.Option(..., "--out", help="Output folder for report.md, results.json and frames.png."),
    trials: int = typer.Option(85, "--trials", "-n", min=2, help="Still scenes per (6-7 m distance, contention)."),
    near_trials: int = typer.Option(20, "--near-trials", min=1, help="Still scenes per (2-5 m distance, contention)."),
    seed: int = typer.Option(0, "--seed", help="Base seed of the scenes' noise and clicks."),
    workers: int = typer.Option(2, "--workers", "-j", min=1, help="Worker processes."),
) -> None:
    """Several frames of a still scene (evaluation/frames_study.py): N = 1, 3, 5, 10 at 2-7 m, coverage of the truth, and moving scenes that must be refused."""
    from sim.truth import ClickModel

    from evaluation.frames_study import click_rms_px, plan, run, write_report

    t0 = time.perf_counter()
    records = run(plan(trials, near_trials, seed), workers=workers)
    protocol = {"trials": trials, "near_trials": near_trials, "seed": seed, "workers": workers, "click_px": click_rms_px(ClickModel()),
                "wall_time_s": time.perf_counter() - t0}
    paths = write_report(out, records, protocol)
    print(f"{len(records)} measurements; report: {paths['report']}, plot: {paths['plot']}")


@app.command("stress-sim")
def stress_sim_command(
    out: Path = typer.Option(..., "--out", help="Output folder for report.md, results.json and plots."),
) -> None:
    """The simulated stress study (evaluation/stress_sim.py): rooms across several surfaces, person, posters, doorways."""
    from evaluation.stress_sim import DEV_SEEDS, HELD_OUT_SEEDS, run_stress_sim, write_stress_sim

    t0 = time.perf_counter()
    dev, held = run_stress_sim(DEV_SEEDS), run_stress_sim(HELD_OUT_SEEDS)
    paths = write_stress_sim(out, dev, held, {"wall_time_s": time.perf_counter() - t0})
    print(f"{len(dev) + len(held)} stress measurements; report: {paths['report']}")


def _two_splits(out: Path, title: str, note: str, dev, held) -> None:
    from evaluation.stress import by_condition, write_stress_report

    paths = write_stress_report(out, title, {"title": title, "notes": [note]}, {"dev": dev, "held-out": held}, [note])
    for split, recs in (("dev", dev), ("held-out", held)):
        for name, f in by_condition(recs, key=lambda r: (r.disparity,), totals=False).items():
            print(f"{split} {name}: {f['n']} cases, mean A {f['mean_A']:.2f} (basic {f['basic_mean_A']:.2f}), good {100 * f['good']:.1f} %, "
                  f"good & A<90 {100 * f['good_and_A_below_90']:.1f} %, 2σ coverage {100 * f['cov_2sigma']:.1f} %")
    print(f"report: {paths['report']}")


@app.command("wall")
def wall_command(out: Path = typer.Option(..., "--out", help="Output folder for report.md, results.json and plots.")) -> None:
    """Segments on a plain wall beside a poster, SGBM on the rendered stereo pair (evaluation/textureless_wall.py)."""
    from evaluation.textureless_wall import DEV_SEEDS, HELD_OUT_SEEDS, run_textureless_wall

    _two_splits(out, "Textureless wall", "Plain wall and poster, SGBM stereo (evaluation/textureless_wall.py); "
                "disparity sgbm = as delivered, sgbm-no-confidence = the same frame without its confidence map.",
                run_textureless_wall(DEV_SEEDS), run_textureless_wall(HELD_OUT_SEEDS))


@app.command("rooms")
def rooms_command(out: Path = typer.Option(..., "--out", help="Output folder for report.md, results.json and plots.")) -> None:
    """Wall or board down to the floor: bent segments in analytic rooms (evaluation/bent_rooms.py)."""
    from evaluation.bent_rooms import DEV_SEEDS, HELD_OUT_SEEDS, run_bent_rooms

    _two_splits(out, "Bent segments", "Wall/board-to-floor rooms (evaluation/bent_rooms.py).",
                run_bent_rooms(DEV_SEEDS), run_bent_rooms(HELD_OUT_SEEDS))


@app.command("gaps")
def gaps_command(out: Path = typer.Option(..., "--out", help="Output folder for report.md, results.json and plots.")) -> None:
    """The doorway and the gap between boxes clicked at their true edges, 1.5-5 m (evaluation/gap_edges.py)."""
    from evaluation.gap_edges import DEV_SEEDS, HELD_OUT_SEEDS, notes, run_gap_edges

    dev, held = run_gap_edges(DEV_SEEDS), run_gap_edges(HELD_OUT_SEEDS)
    lines = notes("dev", dev) + notes("held-out", held)
    _two_splits(out, "Gaps at their true edges", "Doorway and box gap, true edge clicks, 1.5-5 m (evaluation/gap_edges.py); "
                "sim = the default click sigma (1.5 px), sim-exact-clicks = the clicks stated exact (click_px=0), "
                "sim-jittered-clicks = clicks moved by 1.5 px (one sigma per axis) with the default click sigma. "
                + " ".join(f"{line}." for line in lines), dev, held)
    for line in lines:
        print(line)


@app.command("middlebury")
def middlebury_command(
    out: Path = typer.Option(..., "--out", help="Output folder for report.md, results.json and plots."),
    data: Path = typer.Option(None, "--data", show_default="$DEPTHRULER_SHARED/data/middlebury", help="Folder of Middlebury scenes (each with im0.png, im1.png, calib.txt, disp0GT.pfm)."),
    scene: list[str] = typer.Option(None, "--scene", help="Only this scene (repeatable)."),
    max_segments: int = typer.Option(0, "--max-segments", min=0, help="At most this many segments per scene (0 = all selected)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the click jitter and the contention outliers (segment selection is deterministic)."),
    jittered_clicks: int = typer.Option(2, "--jittered-clicks", min=0, help="Jittered click pairs per segment besides the exact end pixels."),
    protocol: str = typer.Option("edge", "--protocol", help="edge: edge-to-edge segments; stress: clicks as people make them (evaluation/stress_middlebury.py)."),
    workers: int = typer.Option(1, "--workers", "-j", min=1, help="Worker processes, one scene each (1 = in this process); with --ray local, Ray's CPUs."),
    ray: str = typer.Option(None, "--ray", help=RAY_HELP),
) -> None:
    """Real stereo: SGBM and contended ground-truth disparity, ground-truth segment lengths."""
    if protocol not in ("edge", "stress"):
        raise typer.BadParameter(f"--protocol {protocol!r} is unknown; use edge or stress")
    if data is None:
        from evaluation.middlebury_data import default_data_dir

        data = default_data_dir()
    if protocol == "stress":
        from evaluation.middlebury import scene_dirs
        from evaluation.report import EvalError
        from evaluation.stress_middlebury import run_stress_middlebury, write_stress_middlebury

        try:
            scene_dirs(data, scene or None)
        except EvalError as exc:
            raise typer.BadParameter(str(exc)) from exc
        t0 = time.perf_counter()
        records = run_stress_middlebury(data, scene or None, max_segments=max_segments or None, seed=seed)
        paths = write_stress_middlebury(out, records, {"data": str(data), "seed": seed, "wall_time_s": time.perf_counter() - t0})
        print(f"{len(records)} stress measurements; report: {paths['report']}")
        return
    from batch.executors import make_executor
    from evaluation.middlebury import ClickJitter, ContentionModel, run_middlebury, scene_dirs, summarize_middlebury, write_middlebury_report
    from batch.errors import BatchError
    from evaluation.report import EvalError

    try:
        n_scenes = len(scene_dirs(data, scene or None))
        executor = make_executor(workers, ray)
    except (EvalError, BatchError) as exc:
        raise typer.BadParameter(str(exc)) from exc
    t0 = time.perf_counter()
    with _progress() as progress, executor:
        task = progress.add_task("SGBM + measuring", total=n_scenes)
        setup, results = run_middlebury(
            data,
            scenes=scene or None,
            max_segments=max_segments or None,
            model=ContentionModel(seed=seed),
            clicks=ClickJitter(extra=jittered_clicks, seed=seed),
            on_progress=lambda _name: progress.advance(task),
            executor=executor,
        )
    setup["wall_time_s"] = time.perf_counter() - t0
    summary = summarize_middlebury(setup, results)
    write_middlebury_report(out, summary, results)
    _print_summary(summary["methods"], f"{out / 'report.md'}", setup["wall_time_s"], None, value="median")


def _print_summary(methods: dict, report_path: str, wall_s: float, gap: dict | None, value: str = "mean") -> None:
    from rich.console import Console
    from rich.table import Table

    from evaluation.report import METHOD_LABELS, fmt

    table = Table(title=f"overall accuracy ({value}, %)")
    table.add_column("method")
    table.add_column(value, justify="right")
    table.add_column("std", justify="right")
    table.add_column("n", justify="right")
    for m, s in methods.items():
        o = s["overall"]
        table.add_row(METHOD_LABELS.get(m, m), fmt(o[value]), fmt(o["std"]), str(o["n"]))
    console = Console()
    console.print(table)
    if gap is not None:
        fp, det = gap.get("false_positive_rate"), gap.get("detection_rate")
        console.print(
            f"gap detector (paper): false positives {fmt(None if fp is None else 100 * fp, 1)} %, "
            f"detection {fmt(None if det is None else 100 * det, 1)} %"
        )
    console.print(f"wall time {wall_s:.1f} s; report: {report_path}")
