"""`depthruler check` end to end on the simulator's ChArUco board: against the accuracy of the same
pairs measured at the true corners, with a right and a wrong (x1.02) baseline, through `video:`
(FFV1 stereo pair, the V4L2 processing path), the CLI, the history file and GET /api/checks."""

from __future__ import annotations

import dataclasses
import json
import os
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from device import open_source
from device.calibration.board import BoardSpec
from history.checks import append_check, checks_path, read_checks
from check.errors import CheckError
from check.pairs import board_pairs
from check.run import report, run_check
from measure.metrics import accuracy
from measure import MeasureOptions, measure_distance

from factories import write_video

W, H = 960, 540
runner = CliRunner()


def board_for(distance_m: float) -> BoardSpec:
    # A board that fills about the same share of the image at every distance (a poster print at 4 m).
    sq = 0.040 * distance_m
    return BoardSpec(7, 5, sq, 0.75 * sq, "DICT_5X5_100")


def sim_spec(distance_m: float, board: BoardSpec, **extra) -> str:
    opts = {"distance": distance_m, "squares": "7x5", "square_mm": board.square_m * 1000,
            "marker_mm": board.marker_m * 1000, "fps": 0, "width": W, "height": H, **extra}
    return "sim:charuco?" + "&".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in opts.items())


def reference_accuracy(result, frames, params) -> float:
    """The evaluation's accuracy (Eq. 8) of the same pairs, clicked at the true corners, against their true 3D length."""
    from sim.charuco import board_truth

    truth = board_truth(params)
    acc = []
    for p in result.pairs:
        a, b = truth.pixels[p.pair.id1], truth.pixels[p.pair.id2]
        m = measure_distance(frames[p.frame], (float(a[0]), float(a[1])), (float(b[0]), float(b[1])))
        g = float(np.linalg.norm(truth.points_m[p.pair.id1] - truth.points_m[p.pair.id2]))
        assert g == pytest.approx(p.pair.length_m, rel=1e-9)  # the printed board's geometry is the scene's
        acc.append(float(accuracy(g, m.distance_m)))
    return float(np.mean(acc))


def test_simulated_board_corners_are_found_where_they_are():
    from sim.charuco import board_truth

    board = board_for(2.0)
    with open_source(sim_spec(2.0, board, yaw=20.0, roll=4.0)) as src:
        frame = src.read()
        params = src.config.scene_params()
    import cv2

    from device.calibration.board import detect_board

    det = detect_board(cv2.aruco.CharucoDetector(board.board()), frame.image)
    truth = board_truth(params)
    err = np.linalg.norm(det.corners - truth.pixels[det.ids], axis=1)
    print(f"{len(det.ids)} corners, error median {np.median(err):.3f} px, max {err.max():.3f} px")
    assert len(det.ids) == board.n_corners and err.max() < 0.5


@pytest.mark.slow
@pytest.mark.parametrize("distance", [1.0, 2.0, 4.0])
def test_check_matches_the_evaluation_and_names_a_wrong_baseline(distance):
    board = board_for(distance)
    with open_source(sim_spec(distance, board)) as src:
        frames = [src.read() for _ in range(2)]
        params = src.config.scene_params()
    result = run_check(frames, board)
    rep = report(result)
    fig = rep["figures"]
    ref = reference_accuracy(result, frames, params)
    print(f"{distance} m: {fig['pairs']} pairs, check mean A {fig['mean_accuracy']:.2f}, evaluation {ref:.2f}, "
          f"bias {fig['bias_pct']:+.2f} %, good {fig['good_share']:.2f}, coverage {fig['interval_coverage']:.2f}, "
          f"fill {fig['fill_rate']:.2f}, plane RMS {fig['plane_rms_mm']:.1f} mm, distance {fig['distance_m']:.3f} m")
    assert fig["pairs"] >= 200 and fig["frames_with_board"] == 2
    assert abs(fig["mean_accuracy"] - ref) <= 1.0
    assert abs(fig["bias_pct"]) <= 0.5
    assert fig["distance_m"] == pytest.approx(distance, rel=0.002) and fig["tilt_deg"] < 0.2  # square on
    assert abs(fig["depth_vs_pose_pct"]) < 0.5
    assert not any("baseline in the calibration" in f["cause"] for f in rep["findings"])
    assert fig["frame_spread_pct"] is not None

    wrong = [dataclasses.replace(f, baseline_m=f.baseline_m * 1.02) for f in frames]  # a calibration's |T| 2 % long
    rep2 = report(run_check(wrong, board))
    fig2 = rep2["figures"]
    print(f"  baseline x1.02: bias {fig2['bias_pct']:+.2f} %, depth vs pose {fig2['depth_vs_pose_pct']:+.2f} %, "
          f"status {rep2['status']}: {rep2['findings'][0]['cause'][:80]}")
    assert fig2["bias_pct"] == pytest.approx(2.0, abs=0.5)
    assert fig2["depth_vs_pose_pct"] == pytest.approx(2.0, abs=0.3)
    first = rep2["findings"][0]
    assert "lengths read 2." in first["measured"] and "long" in first["measured"]
    assert "baseline in the calibration" in first["cause"] and "recalibrate" in first["action"] and rep2["status"] != "ok"


@pytest.mark.slow
def test_history_across_distances_tells_a_disparity_offset_from_a_baseline():
    """A disparity offset of 0.3 px (Z = fx B / (d + 0.3)) reads shorter the farther the board; each check
    alone blames the baseline, the three together find the offset and its size."""
    records, fixed = [], []
    for distance in (1.0, 2.0, 4.0):
        board = board_for(distance)
        with open_source(sim_spec(distance, board)) as src:
            frame = src.read()
        shifted = report(run_check([dataclasses.replace(frame, doffs=0.3)], board), records)
        records.append(shifted)
        fixed.append(report(run_check([dataclasses.replace(frame, baseline_m=frame.baseline_m * 0.98)], board), fixed))
    print([f"{r['figures']['bias_pct']:+.2f}" for r in records], records[-1]["findings"][-1]["cause"][:60])
    last = records[-1]["findings"][-1]
    assert "grows with distance" in last["measured"]
    delta = float(re.search(r"disparity offset of about ([+-][0-9.]+) px", last["cause"]).group(1))
    assert delta == pytest.approx(0.3, abs=0.08)
    assert records[0]["findings"] and not any("grows with distance" in f["measured"] for f in records[1]["findings"])
    steady = fixed[-1]["findings"][-1]
    level = float(re.search(r"stays at ([+-][0-9.]+) %", steady["measured"]).group(1))
    assert level == pytest.approx(-2.0, abs=0.3) and "the baseline" in steady["cause"]


def test_sim_board_options_and_a_wrong_calibration():
    from device import SourceError

    board = board_for(1.0)
    with open_source(sim_spec(1.0, board, baseline_error=0.02)) as src:
        frame = src.read()
        assert src.config.scene_params().charuco == (7, 5, 0.04, 0.03, "DICT_5X5_100")
    assert frame.baseline_m == pytest.approx(0.06 * 1.02, rel=1e-12)
    for bad, match in (("squares=7", "COLSxROWS"), ("dictionary=DICT_9X9", "unknown ArUco dictionary"),
                       ("square_mm=40&marker_mm=50", "markers smaller"), ("baseline_error=0.7", "baseline_error")):
        with pytest.raises(SourceError, match=match):
            open_source(f"sim:charuco?{bad}")


def test_board_pairs_cover_rows_columns_diagonals_short_to_full():
    board = BoardSpec(7, 5, 0.04, 0.03, "DICT_5X5_100")
    pairs = board_pairs(board, range(board.n_corners))
    kinds = {p.kind for p in pairs}
    assert kinds == {"row", "column", "diagonal"}
    lengths = sorted(p.length_m for p in pairs)
    assert lengths[0] == pytest.approx(0.04) and lengths[-1] == pytest.approx(0.04 * np.hypot(5, 3))
    # 6 x 4 inner corners: rows 4 x C(6,2), columns 6 x C(4,2), 45 degree diagonals 2 x (5x3 + 4x2 + 3x1),
    # and the two full-board diagonals (5 across, 3 down); nothing like 2 across, 1 down
    assert sum(p.kind == "row" for p in pairs) == 60 and sum(p.kind == "column" for p in pairs) == 36
    assert sum(p.kind == "diagonal" for p in pairs) == 52 + 2 and len(pairs) == 150
    steps = {(abs(p.id2 % 6 - p.id1 % 6), abs(p.id2 // 6 - p.id1 // 6)) for p in pairs}
    assert (2, 1) not in steps and (5, 3) in steps
    # only detected corners pair up
    assert all({p.id1, p.id2} <= {0, 1, 7, 8, 23} for p in board_pairs(board, [0, 1, 7, 8, 23]))


@pytest.mark.hardware
def test_hardware_check_of_the_whole_chain(tmp_path):
    """With DEPTHRULER_HARDWARE=1 and a camera looking at a printed board, the same check on the real chain
    (sensor, calibration, disparity, method). DEPTHRULER_CHECK_SOURCE (default "oak") names the source and
    DEPTHRULER_CHECK_BOARD the board as "7x5,40,30,DICT_5X5_100" (squares, square mm, marker mm, dictionary)."""
    from cli.main import app

    source = os.environ.get("DEPTHRULER_CHECK_SOURCE", "oak")
    squares, square, marker, dictionary = os.environ.get("DEPTHRULER_CHECK_BOARD", "7x5,40,30,DICT_5X5_100").split(",")
    res = runner.invoke(app, ["check", "--source", source, "--squares", squares, "--square-mm", square, "--marker-mm",
                              marker, "--dictionary", dictionary, "--frames", "5", "--json", "--out", str(tmp_path),
                              "--no-history"])
    assert res.exit_code == 0, res.output
    fig = json.loads(res.output.strip().splitlines()[-1])["figures"]
    print(json.dumps(fig, indent=1))
    assert fig["frames_with_board"] >= 3 and fig["pairs"] >= 50
    assert abs(fig["bias_pct"]) <= 1.0 and fig["interval_coverage"] >= 0.8


def test_no_board_is_a_typed_error():
    with open_source(f"sim:poster?distance=3&fps=0&width={W}&height={H}") as src:
        frame = src.read()
    with pytest.raises(CheckError, match="no 7x5 ChArUco board"):
        run_check([frame], board_for(1.0))


@pytest.mark.slow
def test_video_stereo_pair_of_the_board_gives_its_lengths_within_the_interval(tmp_path):
    """A rectified pair rendered from the board at a known pose (2 m, turned 20 degrees), FFV1 side by side,
    OpenCV YAML calibration, through `video:` (StereoProcessor: rectification + SGBM, as a live pair)."""
    import cv2

    from sim.scenario import make_model
    from sim.scenes import SceneParams, get_view
    from sim.stereo import stereo_pair, true_disparity
    from device.sources.sgbm import round_up_disparities

    board = board_for(2.0)
    params = SceneParams("charuco", distance_m=2.0, yaw_deg=20.0, width=W, height=H,
                         charuco=(7, 5, board.square_m, board.marker_m, board.dictionary))
    model = make_model("indoor")
    left, right = stereo_pair(params, model, np.random.default_rng(0))
    cam = get_view(params).camera
    k = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
    yaml = tmp_path / "stereo.yaml"
    fs = cv2.FileStorage(str(yaml), cv2.FILE_STORAGE_WRITE)
    for name, value in (("M1", k), ("D1", np.zeros((1, 5))), ("M2", k), ("D2", np.zeros((1, 5))), ("R", np.eye(3)),
                        ("T", np.array([[-model.baseline_wide_m], [0.0], [0.0]]))):
        fs.write(name, np.asarray(value, np.float64))
    fs.write("image_width", W)
    fs.write("image_height", H)
    fs.release()
    video = write_video(tmp_path / "board.mkv", [np.hstack([left, right])] * 2)
    ndisp = round_up_disparities(int(np.nanmax(true_disparity(params, model)) * 1.25) + 8)
    spec = f"video:{video}?layout=side-by-side&calib={yaml}&ndisp={ndisp}"
    with open_source(spec) as src:
        frame = src.read()
    result = run_check([frame], board)
    rep = report(result)
    fig = rep["figures"]
    err = np.array([p.measured_m - p.pair.length_m for p in result.pairs])
    half = np.array([(p.interval_m[1] - p.interval_m[0]) / 2 for p in result.pairs])
    print(f"video: {fig['pairs']} pairs, mean A {fig['mean_accuracy']:.2f}, bias {fig['bias_pct']:+.2f} %, "
          f"coverage {fig['interval_coverage']:.3f}, |error|/half-interval median {np.median(np.abs(err) / half):.2f}, "
          f"tilt {fig['tilt_deg']:.1f} deg, distance {fig['distance_m']:.3f} m, fill {fig['fill_rate']:.2f}")
    assert fig["pairs"] >= 100
    assert fig["tilt_deg"] == pytest.approx(20.0, abs=0.3) and fig["distance_m"] == pytest.approx(2.0, rel=0.005)
    # Exact corners (click_px = 0): the intervals are the depth's alone and, through a real matcher, cover
    # about as often as they say; at a mouse's 1.5 px they were wide enough to cover by construction.
    assert 0.80 <= fig["interval_coverage"] <= 0.99
    assert abs(fig["bias_pct"]) <= 1.0

    # The same video through the CLI: --json, the PNG, and the history the service reads.
    from cli.main import app

    db = tmp_path / "svc" / "depthruler.db"
    out = tmp_path / "report"
    res = runner.invoke(app, ["check", "--source", spec, "--squares", "7x5", "--square-mm", f"{board.square_m * 1000:g}",
                              "--marker-mm", f"{board.marker_m * 1000:g}", "--dictionary", "DICT_5X5_100",
                              "--frames", "2", "--json", "--out", str(out), "--db", str(db)])
    assert res.exit_code == 0, res.output
    record = json.loads(res.output.strip().splitlines()[-1])
    assert record["figures"]["frames_with_board"] == 2 and record["kind"] == "video"
    assert record["calibration_sha256"] and len(record["calibration_sha256"]) == 64
    assert (out / "check.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    stored = read_checks(checks_path(db))
    assert len(stored) == 1 and stored[0]["figures"]["pairs"] == record["figures"]["pairs"]

    from fastapi.testclient import TestClient

    from service.app import create_app

    client = TestClient(create_app("sim", db_path=db), base_url="http://127.0.0.1")
    got = client.get("/api/checks").json()
    assert got["count"] == 1 and got["checks"][0]["calibration_sha256"] == record["calibration_sha256"]
    assert client.get("/api/checks", params={"serial": "nope"}).json()["count"] == 0


def test_history_skips_a_cut_line_and_lists_newest_first(tmp_path):
    path = checks_path(tmp_path / "x.db")
    assert path.name == "x-checks.jsonl"
    append_check(path, {"serial": "a", "n": 1})
    append_check(path, {"serial": "b", "n": 2})
    with open(path, "a") as fh:
        fh.write('{"serial": "a", "n": 3')  # a crash mid-line
    assert [r["n"] for r in read_checks(path)] == [2, 1]
    assert [r["n"] for r in read_checks(path, serial="a")] == [1]
    append_check(path, {"serial": "a", "n": 4})  # starts a fresh line after the cut one: nothing else lost
    assert [r["n"] for r in read_checks(path)] == [4, 2, 1]
    assert [r["n"] for r in read_checks(path, limit=1)] == [4]


def test_cli_without_a_board_says_what_to_do(tmp_path):
    from cli.main import app

    res = runner.invoke(app, ["check", "--source", f"sim:poster?distance=3&fps=0&width={W}&height={H}",
                              "--squares", "7x5", "--square-mm", "40", "--marker-mm", "30", "--db", str(tmp_path / "d.db")])
    assert res.exit_code == 1 and "show the whole board" in res.output
    assert not checks_path(tmp_path / "d.db").exists()


@pytest.mark.slow
def test_history_compares_only_checks_made_with_the_same_calibration(tmp_path):
    """The calibration in use is identified from the frames (camera_sha256), so a device's on-board
    calibration counts too: after a recalibration the old checks are not part of the trend."""
    from cli.main import app

    db = tmp_path / "d.db"

    def check(distance: float, baseline_error: float) -> dict:
        board = board_for(distance)
        res = runner.invoke(app, ["check", "--source", sim_spec(distance, board, baseline_error=baseline_error),
                                  "--squares", "7x5", "--square-mm", f"{board.square_m * 1000:g}",
                                  "--marker-mm", f"{board.marker_m * 1000:g}", "--frames", "1", "--json", "--db", str(db)])
        assert res.exit_code == 0, res.output
        return json.loads(res.output.strip().splitlines()[-1])

    old = [check(d, 0.02) for d in (1.0, 2.0, 4.0)]
    assert old[0]["calibration_sha256"] is None  # no calibration file names it ...
    assert len({r["camera_sha256"] for r in old}) == 1 and old[0]["camera"]["baseline_m"] == pytest.approx(0.0612)
    level = float(re.search(r"stays at ([+-][0-9.]+) %", old[-1]["findings"][-1]["measured"]).group(1))
    assert level == pytest.approx(2.0, abs=0.3)  # ... and the three checks of the 2 % baseline error agree
    new = check(4.0, 0.0)
    assert new["camera_sha256"] != old[0]["camera_sha256"]
    assert not any("stays at" in f["measured"] or "grows with distance" in f["measured"] for f in new["findings"])
    assert len(read_checks(checks_path(db))) == 4


def test_corners_are_exact_clicks_so_a_wrong_baseline_shows_in_the_coverage():
    """Corners are detected to a fraction of a pixel: the check measures them at click_px = 0, so the
    interval is the depth's alone. A baseline 3 % long then leaves most lengths outside their interval,
    and the check says so; with a mouse's click error (1.5 px) the same intervals would still cover."""
    board = board_for(1.0)
    with open_source(sim_spec(1.0, board)) as src:
        frames = [src.read() for _ in range(2)]
    fig = report(run_check(frames, board, MeasureOptions(click_px=1.5)))["figures"]  # the option is overridden
    assert fig["interval_coverage"] >= 0.8 and fig["interval_pm_pct"] < 2.0
    wrong = [dataclasses.replace(f, baseline_m=f.baseline_m * 1.03) for f in frames]
    rep = report(run_check(wrong, board))
    print(f"right: coverage {fig['interval_coverage']:.3f}, interval ±{fig['interval_pm_pct']:.2f} %; x1.03: coverage "
          f"{rep['figures']['interval_coverage']:.3f}")
    assert rep["figures"]["interval_coverage"] < 0.6
    assert any("fell inside the reported 95 % interval" in f["measured"] for f in rep["findings"]) and rep["status"] != "ok"
    pairs = run_check(wrong[:1], board).pairs[:60]
    mouse = [measure_distance(wrong[0], p.p1_px, p.p2_px, MeasureOptions(click_px=1.5)) for p in pairs]
    assert np.mean([m.interval_m[0] <= p.pair.length_m <= m.interval_m[1] for m, p in zip(mouse, pairs)]) > 0.8


def test_scale_advice_fits_the_kind_of_camera():
    """'Scale T' means something for a stereo pair processed here; for an OAK or a bag the baseline cancels
    out of lengths and the fix is the device's calibration; for a depth folder it is the depth unit."""
    board = board_for(1.0)
    with open_source(sim_spec(1.0, board)) as src:
        frame = src.read()
    wrong = dataclasses.replace(frame, baseline_m=frame.baseline_m * 1.03)
    # the kind is read from the frame; what is measured does not depend on it, only the words do
    result = run_check([wrong], board)
    assert result.source_kind == "sim"
    words = {}
    for kind in ("sim", "v4l2", "oak", "bag", "depthpng"):
        first = report(dataclasses.replace(result, source_kind=kind))["findings"][0]
        words[kind] = first["cause"] + " " + first["action"]
    assert "scale the calibration's T by 0.97" in words["v4l2"] and words["sim"] == words["v4l2"]
    for kind in ("oak", "bag", "depthpng"):
        assert "scale the calibration's T" not in words[kind] and "baseline in the calibration" not in words[kind], kind
    assert "depthai calibrate" in words["oak"] and "RealSense Viewer" in words["bag"] and "depth_scale" in words["depthpng"]


def test_offset_advice_fits_the_kind_of_camera():
    """A depth error that grows with distance is a disparity offset to fix in the calibration file of a pair
    processed here; an OAK, a bag or a depth folder has no such file: the words name their own fix."""
    results = []  # one check per distance: what is measured does not depend on the kind, only the words do
    for distance in (1.0, 2.0, 4.0):
        board = board_for(distance)
        with open_source(sim_spec(distance, board)) as src:
            frame = dataclasses.replace(src.read(), doffs=0.3)
        results.append(run_check([dataclasses.replace(frame, meta={**frame.meta, "source": "v4l2"})], board))
    assert [r.source_kind for r in results] == ["v4l2"] * 3  # read from the frames
    last = {}
    for kind in ("v4l2", "oak", "bag", "depthpng"):
        records: list[dict] = []
        for result in results:
            records.append(report(dataclasses.replace(result, source_kind=kind), records))
        (grows,) = [x for x in records[-1]["findings"] if "grows with distance" in x["measured"]]
        last[kind] = grows["cause"] + " " + grows["action"]
    assert re.search(r"disparity offset of about \+0\.[23]\d px", last["v4l2"])
    for kind, fix in (("oak", "depthai calibrate"), ("bag", "RealSense Viewer"), ("depthpng", "depth_scale")):
        assert "disparity offset of about" not in last[kind] and "principal points" not in last[kind], kind
        assert fix in last[kind], kind
