"""MCAP export, read back with the mcap reader: images, calibration and measurements match the recording."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import typer
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from factories import record
from typer.testing import CliRunner

from device.errors import RecordingError
from device.formats.mcap import (
    TOPIC_ANNOTATIONS,
    TOPIC_CALIBRATION,
    TOPIC_COLOR,
    TOPIC_CONFIDENCE,
    TOPIC_DEPTH,
    TOPIC_MEASUREMENTS,
    export_mcap,
)
from device.formats.recording import open_recording
from cli.recording import export

MEASUREMENT = {
    "frame_index": 1,
    "p1": [10.0, 20.0],
    "p2": [70.0, 30.0],
    "distance_m": 0.4321,
    "uncertainty_m": 0.004,
    "method": "robust",
    "fit": "line",
    "p1_m": [0.1, 0.2, 2.0],
    "p2_m": [0.5, 0.3, 2.1],
    "warnings": [],
}


def read_mcap(path: Path) -> tuple[dict[str, list], list[dict], dict[str, dict[str, str]]]:
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        proto_topics = [TOPIC_COLOR, TOPIC_DEPTH, TOPIC_CONFIDENCE, TOPIC_CALIBRATION, TOPIC_ANNOTATIONS]
        by_topic: dict[str, list] = {}
        for _schema, channel, message, decoded in reader.iter_decoded_messages(topics=proto_topics):
            by_topic.setdefault(channel.topic, []).append((message.log_time, decoded))
        f.seek(0)
        reader = make_reader(f)
        meas = [json.loads(m.data) for _s, _c, m in reader.iter_messages(topics=[TOPIC_MEASUREMENTS])]
        f.seek(0)
        metadata = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    return by_topic, meas, metadata


def test_export_reads_back_identical(tmp_path: Path) -> None:
    record(tmp_path / "rec", 3)
    rec = open_recording(tmp_path / "rec")
    counts = export_mcap(rec, tmp_path / "out.mcap", measurements=[MEASUREMENT])
    assert counts == {TOPIC_COLOR: 3, TOPIC_DEPTH: 3, TOPIC_CONFIDENCE: 3, TOPIC_CALIBRATION: 3, TOPIC_MEASUREMENTS: 1, TOPIC_ANNOTATIONS: 1}
    by_topic, meas, metadata = read_mcap(tmp_path / "out.mcap")
    times = [t for t, _ in by_topic[TOPIC_COLOR]]
    assert times == sorted(times) and len(set(times)) == 3
    assert (times[1] - times[0]) == pytest.approx(1e9 / 30, abs=2)  # the recorded 30 fps spacing
    md = metadata["depthruler"]
    baseline, doffs = float(md["baseline_m"]), float(md["doffs"])
    assert baseline == rec.baseline_m and doffs == rec.doffs
    for k in range(3):
        frame = rec.frame(k)
        h, w = frame.shape
        _, color = by_topic[TOPIC_COLOR][k]
        assert (color.encoding, color.width, color.height, color.step) == ("bgr8", w, h, 3 * w)
        assert color.data == frame.image.tobytes()
        _, depth = by_topic[TOPIC_DEPTH][k]
        assert depth.encoding == "32FC1"
        z = np.frombuffer(depth.data, "<f4").reshape(h, w)
        want = frame.depth().astype(np.float32)
        assert np.array_equal(np.isnan(z), np.isnan(want)) and np.allclose(z, want, rtol=0, atol=0, equal_nan=True)
        # the disparity comes back from depth and the metadata, to float32 precision
        disp = frame.camera.fx * baseline / z.astype(np.float64) - doffs
        ok = frame.valid(frame.disparity)  # disparities no camera can produce export as no depth
        assert np.max(np.abs(disp[ok] - frame.disparity[ok])) < 1e-3
        _, conf = by_topic[TOPIC_CONFIDENCE][k]
        assert np.max(np.abs(np.frombuffer(conf.data, np.uint8).reshape(h, w) / 255.0 - frame.confidence)) < 1e-6
        _, cal = by_topic[TOPIC_CALIBRATION][k]
        cam = frame.camera
        assert (cal.width, cal.height) == (cam.width, cam.height)
        assert list(cal.K) == [cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1]
        assert list(cal.P)[:3] == [cam.fx, 0, cam.cx] and cal.frame_id == color.frame_id == depth.frame_id
    assert meas[0]["distance_m"] == 0.4321 and meas[0]["frame_index"] == 1
    t_ann, ann = by_topic[TOPIC_ANNOTATIONS][0]
    assert t_ann == times[1]
    assert [(p.x, p.y) for p in ann.points[0].points] == [(10.0, 20.0), (70.0, 30.0)]
    assert ann.texts[0].text.startswith("0.432 m")


def test_export_bad_input(tmp_path: Path) -> None:
    record(tmp_path / "rec", 2)
    out = tmp_path / "out.mcap"
    with pytest.raises(RecordingError, match="frame 5"):
        export_mcap(tmp_path / "rec", out, measurements=[{**MEASUREMENT, "frame_index": 5}])
    assert not out.exists() and not any(p.name.endswith(".partial") for p in tmp_path.iterdir())
    export_mcap(tmp_path / "rec", out)
    with pytest.raises(RecordingError, match="already exists"):
        export_mcap(tmp_path / "rec", out)
    export_mcap(tmp_path / "rec", out, overwrite=True)


def test_export_cli(tmp_path: Path) -> None:
    record(tmp_path / "rec", 2)
    (tmp_path / "m.json").write_text(json.dumps({"measurements": [{**MEASUREMENT, "distance_m": float("nan")}]}).replace("NaN", "null"))
    app = typer.Typer()
    app.command("export")(export)
    app.command("noop")(lambda: None)
    runner = CliRunner()
    args = ["export", str(tmp_path / "rec"), "--mcap", str(tmp_path / "o.mcap"), "--measurements", str(tmp_path / "m.json")]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "/camera/color 2" in result.output and "/measurements 1" in result.output
    by_topic, meas, _ = read_mcap(tmp_path / "o.mcap")
    assert len(by_topic[TOPIC_COLOR]) == 2 and meas[0]["distance_m"] is None
    assert by_topic[TOPIC_ANNOTATIONS][0][1].texts[0].text == "no distance ± 0.004"
    again = runner.invoke(app, args)
    assert again.exit_code == 1 and "already exists" in again.output
    (tmp_path / "bad.json").write_text("[1, 2]")
    bad = runner.invoke(app, ["export", str(tmp_path / "rec"), "--mcap", str(tmp_path / "x.mcap"), "--measurements", str(tmp_path / "bad.json")])
    assert bad.exit_code == 1 and "bad.json" in bad.output


BOX = {  # a box record as GET /api/measurements.json gives it (the fields the annotation reads)
    "kind": "box", "frame_index": 0, "points": [[40.0, 30.0]], "quality": "good", "value": None, "unit": "m",
    "dimensions_m": [0.3012, 0.1338, 0.4465], "dimension_sigmas_m": [0.003, 0.002, 0.004],
    "draw_px": [[30.0, 20.0], [50.0, 20.0], [50.0, 40.0], [30.0, 40.0], [30.0, 25.0], [50.0, 25.0], [50.0, 45.0], [None, None]],
}  # fmt: skip
AREA = {"kind": "area", "frame_index": 1, "value": 0.1026, "unit": "m2", "uncertainty": 0.0012,
        "draw_px": [[10.0, 10.0], [60.0, 10.0], [60.0, 40.0]]}  # fmt: skip


def test_shapes_are_annotated_with_their_outline_and_value(tmp_path: Path) -> None:
    record(tmp_path / "rec", 2)
    full = {**BOX, "draw_px": BOX["draw_px"][:7] + [[30.0, 45.0]]}
    counts = export_mcap(tmp_path / "rec", tmp_path / "out.mcap", measurements=[full, BOX, AREA])
    assert counts[TOPIC_MEASUREMENTS] == 3 and counts[TOPIC_ANNOTATIONS] == 3
    by_topic, meas, _ = read_mcap(tmp_path / "out.mcap")
    assert [m["kind"] for m in meas] == ["box", "box", "area"]
    (_, box), (_, cut), (_, area) = by_topic[TOPIC_ANNOTATIONS]
    # a box: top and base rectangles (closed loops) and four vertical edges; text at the top's centre
    loop, strip = box.points[0].LINE_LOOP, box.points[0].LINE_STRIP
    assert [(len(p.points), p.type) for p in box.points] == [(4, loop), (4, loop)] + [(2, strip)] * 4
    assert [(q.x, q.y) for q in box.points[0].points] == [tuple(p) for p in BOX["draw_px"][:4]]
    assert box.texts[0].text == "0.301 x 0.134 x 0.447 m (good)" and (box.texts[0].position.x, box.texts[0].position.y) == (40.0, 30.0)
    assert [(len(p.points), p.type) for p in area.points] == [(3, loop)] and area.texts[0].text == "0.103 m² ± 0.001"
    assert [len(p.points) for p in cut.points] == [7]  # a base corner the core could not place: the points it could, as one outline
