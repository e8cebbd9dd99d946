"""What the browser tests share: a real ``depthruler serve`` subprocess, Debian's chromium, and a
page that records console errors and failed API responses."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from server_process import ROOT, start_serve

__all__ = ["ROOT", "chromium", "image_point", "launch", "serve", "watch"]
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]


@contextmanager
def serve(folder: Path, source: str, *args: str, config: str = "") -> Iterator[str]:
    """Run ``depthruler serve --source SOURCE ARGS`` with its history in ``folder``; yields the base URL
    once the first frame is there. ``config``: TOML text passed as ``--config`` (server options that
    have no flag, e.g. ``capture_fps``)."""
    if config:
        (folder / "serve.toml").write_text(config)
        args = (*args, "--config", str(folder / "serve.toml"))
    proc, base = start_serve(source, folder / "h.db", folder / "serve.log", *args)
    try:
        yield base
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


def launch(pw) -> object:
    """Debian's chromium, headless, from a started Playwright."""
    return pw.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)


def open_live(page, base: str) -> None:
    """Open the page of the service at ``base`` and wait until it shows its first frame."""
    page.goto(base + "/")
    page.wait_for_function("document.getElementById('canvas').dataset.frameId", timeout=30_000)


def watch(page) -> list[str]:
    """Collect what must not happen on a page: script errors, console errors, API answers >= 400,
    state changes that are not JSON."""
    problems: list[str] = []
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
    page.on(
        "response",
        lambda r: problems.append(f"{r.status} {r.request.method} {r.url}") if "/api/" in r.url and r.status >= 400 else None,
    )
    # the server refuses a state change without a JSON content type (cross-site forms cannot send one)
    page.on(
        "request",
        lambda r: problems.append(f"{r.method} {r.url} without Content-Type: application/json")
        if r.method in ("POST", "PUT", "PATCH") and "/api/" in r.url
        and not (r.headers.get("content-type") or "").startswith("application/json")
        else None,
    )
    page.problems = problems  # type: ignore[attr-defined]
    return problems


def image_point(page, frame: dict, px) -> tuple[float, float]:
    """Viewport coordinates of image pixel ``px`` (pixel-centre convention) on the scaled canvas."""
    box = page.locator("#canvas").bounding_box()
    sx, sy = box["width"] / frame["width"], box["height"] / frame["height"]
    return box["x"] + (px[0] + 0.5) * sx, box["y"] + (px[1] + 0.5) * sy
