"""``POST /api/shapes`` on simulated shape scenes (640x360, sim.shapes) pushed into the ring: the stored
answer is the core's on the same frame and within tolerance of the simulator's truth; bad clicks get
a 422 saying what to change and leave no row; shape rows go through the history routes like segments."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest

from history.frame_file import as_stored
from measure import Frame, MeasureOptions, measure_area, measure_box, measure_distance, measure_height
from service_client import JSON, latest, make_client
from sim.shapes import box_case, panel_case

W, H = 640, 360


@pytest.fixture(scope="module")
def box():
    return box_case(1, range_m=1.0, variant="plain", width=W, height=H)


@pytest.fixture(scope="module")
def panel():
    return panel_case(2, range_m=1.2, width=W, height=H)


@pytest.fixture
def client(tmp_path):
    with make_client(tmp_path) as c:
        yield c


def _push(client, frame: Frame) -> int:
    return client.app.state.ring.push(frame, frozen=True).id


def _shape(client, fid, kind, points, on=None, **options):
    body = {"frame_id": fid, "kind": kind, "points": [list(p) for p in points], "options": options}
    if on is not None:
        body["on"] = [list(p) for p in on]
    return client.post("/api/shapes", json=body)


def test_box_is_the_cores_answer_within_the_truth_and_reads_back(client, box):
    fid = _push(client, box.frame)
    r = _shape(client, fid, "box", [box.click_px])
    assert r.status_code == 200, r.text
    m = r.json()
    core = measure_box(as_stored(box.frame), box.click_px, MeasureOptions())  # on the image as its frame file keeps it
    assert m["kind"] == "box" and m["frame_id"] == fid and m["points"] == [list(box.click_px)] and m["on"] is None
    assert m["dimensions_m"] == list(core.dimensions_m)
    assert m["dimension_sigmas_m"] == list(core.uncertainty_m)
    assert m["dimension_intervals_m"] == [list(i) for i in core.intervals_m]
    assert m["dimensions_m"] == pytest.approx([box.length_m, box.width_m, box.height_m], rel=0.05)
    assert m["value"] is None and m["unit"] == "m" and m["quality"] == core.quality
    assert m["draw_px"] == [list(p) for p in (*core.corners_px, *core.base_corners_px)]
    # the top corners drawn are where the truth has them, to a few pixels
    assert np.abs(np.sort(np.array(m["draw_px"][:4]), 0) - np.sort(np.array(box.corners_px), 0)).max() < 8
    assert m["result"] == core.to_dict() | {"elapsed_ms": m["result"]["elapsed_ms"]}
    assert client.get(f"/api/measurements/{m['id']}").json() == m
    assert [x["id"] for x in client.get("/api/measurements", params={"kind": "box"}).json()] == [m["id"]]
    assert client.get("/api/measurements", params={"kind": "segment"}).json() == []
    thumb = client.get(f"/api/measurements/{m['id']}/thumb.jpg")
    assert thumb.status_code == 200 and thumb.content[:2] == b"\xff\xd8"


def test_height_found_and_on_a_named_base_against_the_truth(client, box):
    fid = _push(client, box.frame)
    found = _shape(client, fid, "height", [box.click_px]).json()
    assert found["value"] == measure_height(box.frame, box.click_px).value
    assert found["value"] == pytest.approx(box.height_m, rel=0.01) and found["unit"] == "m"
    assert found["interval"][0] < found["value"] < found["interval"][1] and found["uncertainty"] > 0
    top, foot = found["draw_px"]
    assert np.hypot(top[0] - box.click_px[0], top[1] - box.click_px[1]) < 1.0  # the top point projects onto the click
    assert foot[1] > top[1]  # the foot lies below it in the image (the camera looks down)
    floor = [(box.click_px[0], H - 20.0)]  # one click on the floor in front of the box
    named = _shape(client, fid, "height", [box.click_px], on=floor)
    assert named.status_code == 200, named.text
    assert named.json()["on"] == [list(floor[0])]
    assert named.json()["value"] == pytest.approx(box.height_m, rel=0.02)


def test_area_and_path_on_a_panel(client, panel):
    fid = _push(client, panel.frame)
    area = _shape(client, fid, "area", panel.clicks_px).json()
    assert area["unit"] == "m2" and area["value"] == measure_area(panel.frame, panel.clicks_px).value
    assert area["value"] == pytest.approx(panel.area_m2, rel=0.03)
    assert area["draw_px"] == [list(p) for p in panel.clicks_px]
    path = _shape(client, fid, "path", panel.clicks_px[:3]).json()
    legs = [measure_distance(panel.frame, panel.clicks_px[k], panel.clicks_px[k + 1]) for k in range(2)]
    assert path["value"] == pytest.approx(sum(m.distance_m for m in legs), rel=1e-12)
    assert path["result"]["parts"] == [m.distance_m for m in legs]


def _with_hole(frame: Frame, x: int, y: int, r: int = 30) -> Frame:
    d = frame.disparity.copy()
    d[y - r : y + r, x - r : x + r] = np.nan
    return Frame(frame.image, d, frame.camera, frame.baseline_m, frame.doffs, None, meta={"source": "sim"})


@pytest.mark.parametrize(
    "kind, points, on, says",
    [
        ("box", "two", None, "a box takes exactly 1 point (a click on its top face), got 2; send one point"),
        ("area", "two", None, "an area needs at least 3 points in order around it, got 2; add points"),
        ("path", "two", "floor", "'on' names the base plane of a height only; leave it out (or null) for a path"),
        ("height", "click", "two", "'on' is 1 click on the base plane or at least 3 around a region of it, got 2"),
        ("box", [(W + 5, 10)], None, f"is outside the {W}x{H} image; pick a point with 0<=x<={W - 1}"),
        ("height", "hole", None, "is not on a surface with depth"),
        ("box", "floor", None, "click the box's top face"),
    ],
)
def test_bad_clicks_get_a_422_that_says_what_to_change_and_store_nothing(client, box, kind, points, on, says):
    hole = (60, 60)
    frame = _with_hole(box.frame, *hole) if points == "hole" else box.frame
    fid = _push(client, frame)
    floor = (box.click_px[0], H - 20.0)
    named = {"two": [box.click_px, floor], "click": [box.click_px], "hole": [hole], "floor": [floor]}
    pts = named.get(points, points) if isinstance(points, str) else points
    r = _shape(client, fid, kind, pts, on=named.get(on) if on else None)
    assert r.status_code == 422, r.text
    assert says in r.json()["detail"]
    assert client.get("/api/measurements").json() == []


def test_unknown_and_evicted_frames_as_for_a_segment(client, box):
    seg = {"p1": [1, 1], "p2": [5, 5]}
    r = _shape(client, 10**9, "box", [box.click_px])
    assert r.status_code == 404 and r.json()["detail"].startswith("frame 1000000000 ")
    assert client.post("/api/measure", json={"frame_id": 10**9, **seg}).status_code == 404
    latest(client, after=client.app.state.ring.capacity + 2)  # frame 1 has left the ring
    gone = _shape(client, 1, "box", [box.click_px])
    assert gone.status_code == 410 == client.post("/api/measure", json={"frame_id": 1, **seg}).status_code
    assert gone.json()["detail"] == client.post("/api/measure", json={"frame_id": 1, **seg}).json()["detail"]
    bad = _shape(client, 1, "box", [box.click_px], methd="robust")  # options refused as /api/measure's
    assert bad.status_code == 422 and "methd" in bad.json()["detail"]
    assert client.get("/api/measurements").json() == []


def test_patch_pin_open_delete_a_shape_row(client, box):
    fid = _push(client, box.frame)
    m = _shape(client, fid, "box", [box.click_px]).json()
    mid = m["id"]
    named = client.patch(f"/api/measurements/{mid}", json={"name": "parcel", "note": "=1+1"}).json()
    assert (named["name"], named["note"], named["dimensions_m"]) == ("parcel", "=1+1", m["dimensions_m"])
    assert client.post(f"/api/measurements/{mid}/pin", headers=JSON).json()["pinned"] is True
    opened = client.post(f"/api/measurements/{mid}/open", headers=JSON).json()
    assert opened["measurement"]["draw_px"] == m["draw_px"] and opened["frame"]["frozen"] is True
    assert opened["frame"]["uid"] == m["frame_uid"]
    assert client.delete(f"/api/measurements/{mid}").json() == {"deleted": mid}
    assert client.get(f"/api/measurements/{mid}").status_code == 404


def test_exports_carry_the_stored_shape(client, box):
    fid = _push(client, box.frame)
    m = _shape(client, fid, "box", [box.click_px]).json()
    (row,) = list(csv.DictReader(io.StringIO(client.get("/api/measurements.csv", params={"units": "mm"}).text)))
    assert (row["kind"], row["fit"], int(row["id"])) == ("box", "box", m["id"])
    got = [float(row[k]) for k in ("length", "width", "height")]
    assert got == pytest.approx([v * 1000 for v in m["dimensions_m"]], abs=0.5)
    assert client.get("/api/measurements.json").json()["measurements"] == [m]


def test_a_full_disk_is_507_and_leaves_no_row(client, panel, monkeypatch):
    import errno

    from history import frame_file

    def enospc(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(frame_file, "write_durably", enospc)
    r = _shape(client, _push(client, panel.frame), "area", panel.clicks_px)
    assert r.status_code == 507 and "full" in r.json()["detail"], r.text
    assert client.get("/api/measurements").json() == []
