"""Exporting a large history: the streamed CSV and JSON against decoding every record whole.

A history of ``--measurements`` (default 10,000) is filled with real measurements (a tilted plane
measured along varied segments, 60-400 samples each, names that look like formulas among them).
Each export is timed both ways in this process, interleaved, CPU time of this process:

- streamed (the service): :meth:`history.store.Store.batches` and :func:`history.export.csv_chunks`
  / :func:`history.export.json_chunks`, the CSV without reading the per-sample arrays, the JSON
  copying them as stored;
- whole (the reference, the service before): every row read with its arrays, each record decoded
  (:func:`history.records.record`), then one CSV text or one ``json.dumps`` of the list.

Both must give the same file (the CSV byte for byte, the JSON as parsed). Reported: CPU ms of a
whole export, the ratio, the longest stretch between two chunks (what one worker thread holds
without yielding to a streamed response) and the largest chunk against the whole file.

    python bench/bench_export.py [--measurements 10000] [--repeats 5] [--write]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from bench.results_file import RESULTS, machine, replace_section

from history import schema
from history.export import csv_chunks, json_chunks
from history.records import record, row_values
from history.store import Store
from measure import Frame, MeasureOptions, PinholeCamera, measure_distance

SECTION = "## Exports"
NAMES = ("", "shelf", "=SUM(A1)", "door, left", "-width", 'the "big" box')


def _plane(w: int = 640, h: int = 480) -> Frame:
    camera = PinholeCamera(fx=500.0, fy=500.0, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)
    rng = np.random.default_rng(0)
    disparity = np.tile(np.linspace(20.0, 30.0, w, dtype=np.float32), (h, 1)) + rng.normal(0, 0.2, (h, w)).astype(np.float32)
    return Frame(image=np.zeros((h, w, 3), np.uint8), disparity=disparity, camera=camera, baseline_m=0.075, meta={"source": "bench"})


def fill(db: Path, n: int, seed: int = 0) -> None:
    """A history database ``db`` of ``n`` measurements of real results on one saved frame: the first
    through :meth:`Store.add` (which saves the frame), the rest inserted in one transaction."""
    frame, rng = _plane(), np.random.default_rng(seed)
    results = []
    for _ in range(24):
        x1, y1 = rng.uniform(20, 200), rng.uniform(20, 460)
        length = rng.uniform(60, 400)
        angle = rng.uniform(-0.6, 0.6)
        p1, p2 = (x1, y1), (min(x1 + length * np.cos(angle), 619), float(np.clip(y1 + length * np.sin(angle), 5, 474)))
        results.append((p1, p2, measure_distance(frame, p1, p2, MeasureOptions()).to_dict()))
    store = Store(db)
    p1, p2, result = results[0]
    store.add(frame_id=0, frame_uid="bench", frame=frame, source="bench", p1=p1, p2=p2, options={}, result=result)
    store.close()
    con = schema.open_writer(db)
    rows = []
    for k in range(1, n):
        p1, p2, result = results[k % len(results)]
        extra = {"name": NAMES[k % len(NAMES)], "note": f"note {k}"} if k % 3 else None
        rows.append(row_values(time.time(), k, "bench", "bench", p1, p2, {"method": "robust"}, result, None, extra))
    with con:
        con.execute("BEGIN")
        con.executemany(schema.insert_sql("measurements", schema.MEASUREMENT_INSERT), rows)
    con.close()


def _whole_rows(db: Path) -> list:
    con = schema.open_reader(db)
    try:
        return con.execute("SELECT * FROM measurements ORDER BY id").fetchall()
    finally:
        con.close()


def whole_csv(db: Path) -> str:
    """The reference: every row with its arrays, each record decoded, one text."""
    return "".join(csv_chunks([_whole_rows(db)]))


def whole_json(db: Path) -> bytes:
    """The reference: every record decoded, one ``json.dumps`` of the list (as JSONResponse did)."""
    records = [record(r) for r in _whole_rows(db)]
    return json.dumps({"measurements": records}, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()


def _timed_chunks(chunks: Iterable[str | bytes]) -> tuple[float, float, int, int]:
    """CPU s of consuming ``chunks``, the longest CPU stretch between two chunks, largest and total size."""
    t0 = last = time.process_time()
    longest, largest, total = 0.0, 0, 0
    for c in chunks:
        now = time.process_time()
        longest, last = max(longest, now - last), now
        largest, total = max(largest, len(c)), total + len(c)
    return time.process_time() - t0, longest, largest, total


def run(n: int, repeats: int) -> dict[str, dict[str, float]]:
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "export.db"
        fill(db, n)
        store = Store(db)
        try:
            kinds: dict[str, tuple[Callable[[], Iterable], Callable[[], str | bytes]]] = {
                "CSV": (lambda: csv_chunks(store.batches()), lambda: whole_csv(db)),
                "JSON": (lambda: json_chunks(store.batches(arrays=True)), lambda: whole_json(db)),
            }
            streamed_csv = "".join(csv_chunks(store.batches()))
            if streamed_csv != whole_csv(db):
                raise SystemExit("the streamed CSV differs from the whole one")
            if json.loads(b"".join(json_chunks(store.batches(arrays=True)))) != json.loads(whole_json(db)):
                raise SystemExit("the streamed JSON differs from the whole one")
            out = {}
            for name, (streamed, whole) in kinds.items():
                s_cpu, s_hold, w_cpu = [], [], []
                largest = total = 0
                for _ in range(repeats):  # interleaved: both see the same state of a shared host
                    cpu, hold, largest, total = _timed_chunks(streamed())
                    s_cpu.append(cpu)
                    s_hold.append(hold)
                    t0 = time.process_time()
                    whole()
                    w_cpu.append(time.process_time() - t0)
                out[name] = {
                    "streamed_ms": float(np.median(s_cpu)) * 1e3, "whole_ms": float(np.median(w_cpu)) * 1e3,
                    "hold_ms": float(np.median(s_hold)) * 1e3, "largest": largest, "total": total,
                }  # fmt: skip
            return out
        finally:
            store.close()


def report(rows: dict[str, dict[str, float]], n: int, repeats: int, loads: tuple[float, float], date: str) -> str:
    table = "".join(
        f"| {name} | {r['whole_ms']:.0f} | {r['streamed_ms']:.0f} | {r['whole_ms'] / r['streamed_ms']:.1f}x | "
        f"{r['hold_ms']:.1f} | {r['largest'] / 1e3:.0f} kB of {r['total'] / 1e6:.1f} MB |\n"
        for name, r in rows.items()
    )
    return (
        f"{SECTION}\n\n"
        f"`bench/bench_export.py` (`depthruler bench export --write`): a history of {n:,} real measurements "
        "(60-400 samples each), each export timed whole (every record decoded with its per-sample arrays, one text: "
        "the service before) and streamed (`Store.batches` of 500 rows: the CSV without the arrays, the JSON copying "
        f"them as stored), interleaved, median of {repeats}, CPU time of this process; both give the same file. "
        "`longest stretch` is the most CPU between two chunks of the streamed export (the whole export is one stretch).\n\n"
        "| export | whole CPU ms | streamed CPU ms | ratio | longest stretch ms | largest chunk |\n"
        "| --- | --- | --- | --- | --- | --- |\n"
        f"{table}\nMachine: {machine()}; {date}; 1-minute load average {loads[0]:.1f} before, {loads[1]:.1f} after.\n"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--measurements", type=int, default=10_000, help="measurements in the history (default 10000)")
    ap.add_argument("--repeats", type=int, default=5, help="timed exports of each kind, each way (default 5)")
    ap.add_argument("--write", action="store_true", help="record the table in bench/RESULTS.md")
    args = ap.parse_args(argv)
    before = os.getloadavg()[0]
    rows = run(args.measurements, args.repeats)
    text = report(rows, args.measurements, args.repeats, (before, os.getloadavg()[0]), time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()))
    print(text)
    if args.write:
        replace_section(SECTION, text)
        print(f"recorded in {RESULTS.name} ({SECTION})")


if __name__ == "__main__":
    main()
