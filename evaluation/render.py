"""Re-render the committed reports' report.md from their results.json, without re-running a study.

``python -m evaluation.render docs/eval`` rewrites every ``<dir>/report.md`` whose ``results.json``
it recognises; ``--check`` only compares and exits 1 when a report differs from what its generator
writes (a hand edit, or a generator changed without re-rendering). Steps: read results.json, pick the
generator by the keys it holds (``kind``), render.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any


def kind(data: dict[str, Any]) -> str:
    """Which study wrote ``data``: "sim", "middlebury", "stress-middlebury", "stress-sim", "stress" (a
    stress table study that names its title and notes: wall, rooms, gaps), "frames" or "shapes"."""
    if data.get("kind") == "shapes":
        return "shapes"
    if "methods" in data and "gap" in data:
        return "sim"
    if "conditions" in data:
        return "middlebury"
    if "splits" in data and "title" in data.get("setup", {}):
        return "stress"
    if "splits" in data:
        return "stress-middlebury" if "data" in data.get("setup", {}) else "stress-sim"
    if "cells" in data.get("summary", {}):
        return "frames"
    raise ValueError("results.json of no known study (sim, middlebury, stress, frames)")


def render(folder: Path) -> str:
    """The report.md that ``folder``'s results.json gives."""
    data = json.loads((folder / "results.json").read_text())
    which = kind(data)
    if which == "shapes":
        from evaluation.shapes_report import shapes_markdown

        return shapes_markdown(data["summary"], data["protocol"])
    if which == "sim":
        from evaluation.sim_report import PLOTS, sim_markdown

        return sim_markdown(data, PLOTS)
    if which == "middlebury":
        from evaluation.middlebury import middlebury_markdown, plot_names

        return middlebury_markdown(data, plot_names())
    if which == "stress-middlebury":
        from evaluation.stress_middlebury import stress_middlebury_markdown

        return stress_middlebury_markdown(data)
    if which == "stress":
        from evaluation.stress import stress_markdown

        return stress_markdown(data["setup"]["title"], data["setup"]["notes"], data)
    if which == "stress-sim":
        from evaluation.stress_sim import stress_sim_markdown

        return stress_sim_markdown(data)
    from evaluation.frames_study import frames_markdown

    return frames_markdown(data["summary"], data["protocol"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="folder of report folders, e.g. docs/eval")
    parser.add_argument("--check", action="store_true", help="compare only; exit 1 when a report differs")
    args = parser.parse_args(argv)
    stale = []
    for folder in sorted(p.parent for p in args.root.glob("*/results.json")):
        text = render(folder)
        if (folder / "report.md").read_text() != text:
            stale.append(folder)
            if not args.check:
                (folder / "report.md").write_text(text)
        print(f"{folder}: {'differs' if folder in stale and args.check else 'rendered' if folder in stale else 'up to date'}")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
