"""`depthruler batch` and the executors: same answers on every executor, resume after a kill,
re-measurement of the service's history, error rows, diff; the evaluation on the executors."""

from __future__ import annotations

import csv
import json
import math
import os
import signal

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from batch_tables import invoke, killed_after_first_part, stable, truth, write_tasks
from batch.diff import diff_results
from batch.executors import InProcessExecutor, PoolExecutor, RayExecutor, make_executor
from batch.run import close_readers, run_batch
from batch.tasks import Task, read_tasks
from cli.main import app as cli
from device.formats.recording import open_recording


@pytest.mark.slow
def test_same_results_in_process_pool_and_ray(archive, tmp_path, ray_session):
    tasks_csv = write_tasks(archive / "tasks.csv", archive, extra_rows=[["rec_poster", 9, 10, 10, 100, 100, "robust", "missing"]])
    tasks = read_tasks(tasks_csv)
    assert len(tasks) == 2 * 4 * 3 * 2 + 1
    outs = {}
    for name, ex in (("inproc", InProcessExecutor()), ("pool", PoolExecutor(2))):
        with ex:
            summary = run_batch(tasks, tmp_path / f"{name}.parquet", ex)
        assert summary["measured"] == len(tasks) and summary["rows"] == len(tasks)
        outs[name] = tmp_path / f"{name}.parquet"
    close_readers()
    # Ray through the command line: --ray auto joins the session's Ray instance (2 CPUs)
    outs["ray"] = tmp_path / "ray.parquet"
    res = invoke(["batch", str(tasks_csv), "--out", str(outs["ray"]), "--ray", "auto"])
    assert "on Ray (2 CPUs on 1 node(s), 2 workers)" in res and f"{len(tasks)} tasks measured (1 error rows)" in res
    assert ray_session.is_initialized()  # the command did not shut down a Ray it did not start
    ref = stable(outs["inproc"])
    assert [r["task"] for r in ref] == list(range(len(tasks)))
    assert stable(outs["pool"]) == ref
    assert stable(outs["ray"]) == ref
    workers = {name: {r["worker"] for r in pq.read_table(p).to_pylist()} for name, p in outs.items()}
    me = f":{os.getpid()}"
    assert workers["inproc"] == {next(iter(workers["inproc"]))} and next(iter(workers["inproc"])).endswith(me)
    assert not any(w.endswith(me) for w in workers["pool"] | workers["ray"])  # really elsewhere
    # the answers are measurements of the recorded scenes, not just equal to each other
    answered = [r for r in ref if r["error"] is None]
    assert len(answered) == len(tasks) - 1
    on_truth = [r for r in answered if r["opt_method"] == "robust" and r["label"].endswith("/0")]
    assert len(on_truth) == 8
    for r in on_truth:
        assert r["distance_m"] == pytest.approx(float(r["label"].split("/")[2]), rel=0.03)
    assert {r["method"] for r in answered} == {"robust", "paper", "basic"}
    assert all(r["version"] and len(r["p1_m"]) == 3 and r["uncertainty_m"] > 0 for r in answered)
    # the frame that is not in the recording is an error row that keeps its task's columns
    (missing,) = [r for r in ref if r["error"] is not None]
    assert missing["label"] == "missing" and missing["frame"] == 9 and missing["distance_m"] is None
    assert "frame 9 is not in" in missing["error"] and "4 complete frames" in missing["error"]


def test_missing_frame_file_is_an_error_row(archive, tmp_path):
    damaged = tmp_path / "rec_tilted"
    import shutil

    shutil.copytree(archive / "rec_tilted", damaged)
    rec = open_recording(damaged)
    (damaged / rec.entries[2].files["disparity"]).unlink()
    t = truth(damaged, 1)
    rows = [[str(damaged), i, *t["p1_px"], *t["p2_px"], "robust", f"f{i}"] for i in range(4)]
    tasks_csv = tmp_path / "t.csv"
    with tasks_csv.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["source", "frame", "p1_x", "p1_y", "p2_x", "p2_y", "method", "label"])
        w.writerows(rows)
    res = invoke(["batch", str(tasks_csv), "--out", str(tmp_path / "r.parquet"), "--workers", "1"])
    assert "4 tasks measured (1 error rows)" in res
    out = {r["label"]: r for r in pq.read_table(tmp_path / "r.parquet").to_pylist()}
    assert out["f2"]["error"] and "disparity" in out["f2"]["error"] and out["f2"]["error_type"] == "RecordingError"
    assert all(out[k]["error"] is None and out[k]["distance_m"] > 0 for k in ("f0", "f1", "f3"))
    close_readers()


@pytest.mark.slow
def test_resume_after_a_killed_run(archive, tmp_path):
    # enough tasks that the run is still going when its first part is on disk
    tasks_csv = write_tasks(tmp_path / "many.csv", archive, methods=("robust", "basic"), jitter=tuple(range(0, 24, 2)))
    n = len(read_tasks(tasks_csv))
    out = tmp_path / "r.parquet"
    parts = tmp_path / "r.parquet.parts"
    killed = killed_after_first_part(["batch", str(tasks_csv), "--out", str(out), "--workers", "1"], parts, timeout=120)
    assert killed == -signal.SIGKILL, "the run ended before it could be killed"
    assert not out.exists()
    before = pq.read_table(parts).to_pylist() if parts.is_dir() else []
    done = {r["task"] for r in before}
    assert 0 < len(done) < n and len(before) == len(done)
    (first_run,) = {r["run"] for r in before}

    res = invoke(["batch", str(tasks_csv), "--out", str(out), "--workers", "1", "--resume"])
    assert f"{n} tasks, {len(done)} already done; running {n - len(done)}" in res
    rows = pq.read_table(out).to_pylist()
    assert sorted(r["task"] for r in rows) == list(range(n))  # every task once
    assert {r["task"] for r in rows if r["run"] == first_run} == done  # the killed run's rows kept...
    assert len({r["run"] for r in rows}) == 2 and sum(r["run"] != first_run for r in rows) == n - len(done)  # ...not redone
    assert not parts.exists()
    # other options are other tasks: resuming with them is refused
    res = CliRunner().invoke(cli, ["batch", str(tasks_csv), "--out", str(out), "--resume", "--set", "window=7"])
    assert res.exit_code == 1 and "--set options changed" in res.output
    # a finished run is not overwritten by accident
    res = CliRunner().invoke(cli, ["batch", str(tasks_csv), "--out", str(out), "--workers", "1"])
    assert res.exit_code == 1 and "--resume" in res.output and "--overwrite" in res.output
    close_readers()


@pytest.mark.slow
def test_from_history_reproduces_stored_measurements(archive, tmp_path):
    from fastapi.testclient import TestClient

    from device.formats.recording import ReplayConfig, ReplaySource
    from service.app import create_app

    # a history made by the service itself, measuring on a replayed recording (its disparity is on
    # the recording's 1/64 px grid, so any lossless-on-that-grid frame store keeps it exactly)
    db = tmp_path / "history.db"
    t = truth(archive / "rec_poster", 0)
    p1, p2 = list(t["p1_px"]), list(t["p2_px"])
    variants = ({}, {"method": "paper"}, {"method": "basic", "window": 7}, {"seed": 5, "support_fraction": 0.6}, {})
    factory = lambda: ReplaySource(ReplayConfig(archive / "rec_poster", loop=True))  # noqa: E731
    with TestClient(create_app(factory, db_path=db, capture_fps=50.0), base_url="http://127.0.0.1") as client:
        after = 0
        for opts in variants:
            r = client.get("/api/frames/latest", params={"after": after, "wait": 5})
            assert r.status_code == 200, r.text
            after = r.json()["id"]
            m = client.post("/api/measure", json={"frame_id": after, "p1": p1, "p2": p2, "options": opts})
            assert m.status_code == 200, m.text
        listed = [rec["id"] for rec in client.get("/api/measurements").json()]
        stored = {mid: client.get(f"/api/measurements/{mid}").json() for mid in listed}
    assert len(stored) == len(variants)
    ids = sorted(stored)

    out = tmp_path / "h.parquet"
    invoke(["batch", "--from-history", str(db), "--out", str(out), "--workers", "2"])
    rows = pq.read_table(out).to_pylist()
    assert [r["history_id"] for r in rows] == ids
    fields = {"distance_m", "uncertainty_m", "basic_distance_m", "p1_m", "p2_m", "samples_px", "support", "warnings",
              "method", "fit", "n_samples", "n_valid", "n_support", "gap_detected"}  # fmt: skip
    for r in rows:
        want = stored[r["history_id"]]
        assert r["error"] is None and r["frame_uid"] == want["frame_uid"]
        assert {"distance_m", "uncertainty_m", "p1_m", "p2_m", "n_support", "warnings"} <= set(want)
        for f in (fields | {"quality", "reasons", "interval_m"}) & set(want):
            assert r[f] == want[f], f  # exactly: the same frame, options and method
        assert {k: r[f"opt_{k}"] for k in want["options"]} == want["options"]
    assert {r["opt_method"] for r in rows} == {"robust", "paper", "basic"}

    # a saved frame that is gone is its measurements' error row; the history itself is never changed
    victim = stored[ids[1]]["frame_uid"]
    (saved,) = [p for p in (tmp_path / "history-frames").iterdir() if p.stem == victim]
    saved.unlink()
    before = db.read_bytes()
    out2 = tmp_path / "h2.parquet"
    invoke(["batch", "--from-history", str(db), "--out", str(out2), "--workers", "1"])
    rows2 = {r["history_id"]: r for r in pq.read_table(out2).to_pylist()}
    for mid in ids:
        lost = stored[mid]["frame_uid"] == victim
        assert (rows2[mid]["error"] is not None) == lost
        assert not lost or ("cannot read the saved frame" in rows2[mid]["error"] and rows2[mid]["error_type"] == "HistoryError")
    assert db.read_bytes() == before


def _frame_file(frame) -> bytes:
    """A ``.frame`` file as the service writes it (history/frame_file.py's documented layout)."""
    import io
    import zipfile

    import cv2

    from device.formats.recording import encode_confidence, encode_disparity

    code, _ = encode_disparity(frame.disparity)
    info = {"camera": {k: getattr(frame.camera, k) for k in ("fx", "fy", "cx", "cy", "width", "height")},
            "baseline_m": frame.baseline_m, "doffs": frame.doffs, "timestamp": frame.timestamp, "meta": {"source": "sim"}}  # fmt: skip
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zf:
        zf.writestr("disparity.png", cv2.imencode(".png", code)[1].tobytes())
        zf.writestr("color.jpg", cv2.imencode(".jpg", frame.image)[1].tobytes())
        zf.writestr("confidence.png", cv2.imencode(".png", encode_confidence(frame.confidence))[1].tobytes())
        zf.writestr("frame.json", json.dumps(info))
    return out.getvalue()


def test_history_reads_both_saved_frame_formats(archive, tmp_path):
    from batch.history import HistoryFrames

    frame = open_recording(archive / "rec_poster").frame(1)
    (tmp_path / "a.frame").write_bytes(_frame_file(frame))
    try:  # the service's own writer, where this tree has it
        from history.frame_file import encode_frame

        (tmp_path / "b.frame").write_bytes(encode_frame(frame))
    except ImportError:
        pass
    np.savez(tmp_path / "c.npz", image=frame.image, disparity=frame.disparity, confidence=frame.confidence,
             camera=np.array([frame.camera.fx, frame.camera.fy, frame.camera.cx, frame.camera.cy, frame.camera.width, frame.camera.height]),
             numbers=np.array([frame.baseline_m, frame.doffs, frame.timestamp]), meta=np.array("{}"))  # fmt: skip
    reader = HistoryFrames(tmp_path / "h.db")
    for path in sorted(tmp_path.glob("[abc].*")):
        got = reader.frame(str(path))
        assert np.array_equal(got.disparity, frame.disparity, equal_nan=True), path.name  # on the 1/64 px grid: exact
        assert np.array_equal(got.confidence, frame.confidence) and got.camera == frame.camera and got.baseline_m == frame.baseline_m
        assert np.abs(got.image.astype(int) - frame.image).mean() < (3 if path.suffix == ".frame" else 1e-9)  # JPEG
    (tmp_path / "bad.frame").write_bytes(b"not a zip")
    with pytest.raises(Exception, match="cannot read the saved frame"):
        reader.frame(str(tmp_path / "bad.frame"))
    with pytest.raises(Exception, match="size cap"):
        reader.frame("dropped:abc")


def test_diff_counts_moves_beyond_uncertainty(archive, tmp_path):
    tasks_csv = write_tasks(tmp_path / "t.csv", archive, methods=("",), jitter=(0, 3))
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    invoke(["batch", str(tasks_csv), "--out", str(a), "--workers", "1"])
    invoke(["batch", str(tasks_csv), "--out", str(b), "--workers", "1", "--set", "method=basic"])
    ra, rb = pq.read_table(a).to_pylist(), pq.read_table(b).to_pylist()
    assert {r["opt_method"] for r in ra} == {"robust"} and {r["opt_method"] for r in rb} == {"basic"}
    want = sum(abs(y["distance_m"] - x["distance_m"]) > max(x["uncertainty_m"], y["uncertainty_m"]) for x, y in zip(ra, rb))
    d = diff_results(a, b)
    assert d["matched"] == len(ra) == 16 and d["moved_beyond_uncertainty"] == want > 0
    assert d["status"] == {"answered -> answered": 16}
    assert d["runs"]["a"]["options"] == {} and d["runs"]["b"]["options"] == {"method": "basic"}
    same = diff_results(a, a)
    assert same["moved_beyond_uncertainty"] == 0 and same["unchanged_exactly"] == 16
    res = invoke(["batch", "diff", str(a), str(b), "--json"])
    assert json.loads(res)["moved_beyond_uncertainty"] == want
    assert "B options: method=basic" in invoke(["batch", "diff", str(a), str(b)])
    close_readers()


def test_bad_tables_are_typed_errors(archive, tmp_path):
    """What stops a run before it starts: a table without a required column, results not named *.parquet, no workers."""
    bad = tmp_path / "bad.csv"
    bad.write_text("source,frame,p1_x,p1_y,p2_x\nrec,0,1,2,3\n")
    res = CliRunner().invoke(cli, ["batch", str(bad), "--out", str(tmp_path / "r.parquet")])
    assert res.exit_code == 1 and "lacks the column(s) p2_y" in res.output
    bad.write_text("source,frame,p1_x,p1_y,p2_x,p2_y\n")
    res = CliRunner().invoke(cli, ["batch", str(bad), "--out", str(tmp_path / "r.parquet")])
    assert res.exit_code == 1 and "holds no task rows" in res.output
    t = truth(archive / "rec_poster", 0)
    good = tmp_path / "opt.jsonl"
    good.write_text(json.dumps({"source": str(archive / "rec_poster"), "frame": 0, "p1_x": t["p1_px"][0], "p1_y": t["p1_px"][1],
                                "p2_x": t["p2_px"][0], "p2_y": t["p2_px"][1]}))  # fmt: skip
    res = CliRunner().invoke(cli, ["batch", str(good), "--out", str(tmp_path / "r.csv")])
    assert res.exit_code == 1 and "*.parquet" in res.output
    assert not list(tmp_path.glob("r.*"))
    with pytest.raises(Exception, match="at least 1"):
        make_executor(0)


@pytest.mark.slow
def test_eval_sim_same_on_every_executor(ray_session):
    from evaluation.sim_study import plan_sim, run_sim

    jobs = plan_sim(3, seed=7, gap_fraction=0.0)
    runs = {}
    for name, ex in (("serial", InProcessExecutor()), ("pool", PoolExecutor(2)), ("ray", RayExecutor())):
        with ex:
            runs[name] = run_sim(jobs, executor=ex)

    def answers(records):
        return [(r.job.index, r.truth_m, r.clicks_px, [(o.method, o.distance_m, o.gap_detected, o.fit, o.error) for o in r.outcomes]) for r in records]

    ref = answers(runs["serial"])
    assert len(ref) == 3 and all(math.isfinite(d) for *_, outs in ref for _, d, *_ in outs)
    assert answers(runs["pool"]) == ref and answers(runs["ray"]) == ref


@pytest.mark.slow
def test_eval_middlebury_same_on_ray(ray_session, middlebury_dir):
    from evaluation.middlebury import ClickJitter, run_middlebury

    kw = dict(scenes=["Pipes", "Recycle"], max_segments=1, clicks=ClickJitter(extra=1, seed=4))
    setup_a, serial = run_middlebury(middlebury_dir, **kw)
    with RayExecutor() as ex:
        setup_b, on_ray = run_middlebury(middlebury_dir, executor=ex, **kw)

    def answers(results):
        return [(r.scene, r.condition, r.p1_px, r.p2_px, r.truth_m, [(o.method, o.distance_m, o.gap_detected) for o in r.outcomes]) for r in results]

    assert len(serial) >= 4 and answers(on_ray) == answers(serial)
    assert list(setup_b["scenes"]) == list(setup_a["scenes"]) == ["Pipes", "Recycle"]
    assert np.isclose(setup_b["scenes"]["Pipes"]["sgbm_valid_fraction"], setup_a["scenes"]["Pipes"]["sgbm_valid_fraction"], rtol=0, atol=0)


def test_groups_read_each_frame_once_and_new_fields_flow_through(archive, tmp_path, monkeypatch):
    from batch.tasktable import group_tasks
    from measure import measure_distance

    tasks = read_tasks(write_tasks(tmp_path / "t.csv", archive, methods=("robust",), jitter=(0, 1, 2)))
    for workers in (1, 2, 8):
        groups = group_tasks(tasks, workers, {})
        assert sorted(t.index for g in groups for t in g.tasks) == list(range(len(tasks)))
        frames = [(g.source, t.frame) for g in groups for t in g.tasks]
        # a frame's tasks are all in one group, consecutive: it is read once
        assert sum(1 for i, f in enumerate(frames) if i == 0 or frames[i - 1] != f) == len(set(frames)) == 8
        # at least 4 groups per worker where frames allow it (24 tasks on 8 frames)
        assert len(groups) == {1: 4, 2: 8, 8: 8}[workers]
    # a source read in order stays one group, or its frames would be decoded by several workers
    seq = [Task(i, "depthpng:/archive/a", i % 5, (1.0, 1.0), (9.0, 9.0)) for i in range(40)]
    (group,) = group_tasks(seq, 2, {})
    assert [t.frame for t in group.tasks] == sorted(t.frame for t in seq)

    # every Measurement field has its column in the fixed result schema, with the type its values have
    from batch.schema import MEASUREMENT_TYPES, encode_rows, result_schema

    out = tmp_path / "r.parquet"
    run_batch(tasks[:3], out, InProcessExecutor())
    t = pq.read_table(out)
    row = t.to_pylist()[0]
    assert set(MEASUREMENT_TYPES) == set(row) & set(MEASUREMENT_TYPES)
    real = measure_distance(open_recording(tasks[0].source.partition(":")[2]).frame(0), tasks[0].p1, tasks[0].p2)
    assert set(real.to_dict()) == set(MEASUREMENT_TYPES)
    assert str(t.schema.field("interval_m").type) == "list<element: double>" and str(t.schema.field("reasons").type).startswith("list<")
    assert row["quality"] in ("good", "check", "unreliable") and len(row["interval_m"]) == 2
    # a column outside the schema is refused loudly, never dropped
    with pytest.raises(ValueError, match="outside the result schema"):
        encode_rows([{**row, "detail": 1}], result_schema())


def test_a_group_that_starts_with_an_error_row_keeps_its_valid_rows(archive, tmp_path):
    """Columns once came from a group's first row: an error row first lost every valid row's answer."""
    rec = archive / "rec_poster"
    t = truth(rec, 0)
    (x1, y1), (x2, y2) = t["p1_px"], t["p2_px"]
    rows = [[str(rec), 0, 5000, 10, 100, 100, "", "outside"]]  # a pixel outside the image, first in its frame
    rows += [[str(rec), 0, x1 + d, y1, x2 - d, y2, m, f"ok{d}{m}"] for d in range(4) for m in ("robust", "basic")]
    table = tmp_path / "nine.csv"
    with table.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["source", "frame", "p1_x", "p1_y", "p2_x", "p2_y", "method", "label"])
        w.writerows(rows)
    frame = open_recording(rec).frame(0)
    from measure import MeasureOptions, measure_distance

    want = {f"ok{d}{m}": measure_distance(frame, (x1 + d, y1), (x2 - d, y2), MeasureOptions(method=m)).distance_m
            for d in range(4) for m in ("robust", "basic")}  # fmt: skip
    results = {}
    for name, ex in (("inproc", InProcessExecutor()), ("pool", PoolExecutor(2))):
        with ex:
            run_batch(read_tasks(table), tmp_path / f"{name}.parquet", ex)
        results[name] = stable(tmp_path / f"{name}.parquet")
    close_readers()
    ref = results["inproc"]
    assert len(ref) == 9 and results["pool"] == ref
    by_label = {r["label"]: r for r in ref}
    assert by_label["outside"]["error_type"] == "MeasureError" and by_label["outside"]["distance_m"] is None
    for label, d in want.items():
        assert by_label[label]["error"] is None and by_label[label]["distance_m"] == d, label


class _CountingItems:
    """An iterable that counts how many items the executor has taken from it."""

    def __init__(self, n: int) -> None:
        self.n, self.taken = n, 0

    def __iter__(self):
        for i in range(self.n):
            self.taken += 1
            yield i


@pytest.mark.parametrize("executor", ["pool", pytest.param("ray", marks=pytest.mark.slow)])  # Ray's start is the full suite's
def test_executors_keep_a_bounded_window_of_groups_in_flight(executor, request):
    from batch.executors import PoolExecutor, RayExecutor, window

    if executor == "ray":
        request.getfixturevalue("ray_session")
    items = _CountingItems(40)
    with (PoolExecutor(2) if executor == "pool" else RayExecutor()) as ex:
        stream = ex.imap(json.dumps, items)
        next(stream)
        assert items.taken <= window(ex.workers) + 1 < 40
        rest = sorted(i for i, _ in stream)
    assert items.taken == 40 and len(rest) == 39
