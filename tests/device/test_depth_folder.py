"""`depthpng:DIR`: folders of 16-bit depth PNGs with an intrinsics JSON (Open3D and ZED layouts)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from device import open_source
from device.sources.depth_folder import DEFAULT_BASELINE_M
from device.errors import CalibrationError, RecordingError, SourceError, SourceNotFound
from device.formats.recording import EndOfRecording, RecordingWriter, open_recording

W, H = 80, 60
FX, FY, CX, CY = 70.0, 71.0, 39.5, 29.25


def depth_mm(k: int) -> np.ndarray:
    rng = np.random.default_rng(k)
    d = rng.integers(400, 9000, (H, W)).astype(np.uint16)
    d[rng.random((H, W)) < 0.1] = 0
    return d


def colour(k: int) -> np.ndarray:
    return np.random.default_rng(100 + k).integers(0, 256, (H, W, 3), dtype=np.uint8)


def open3d_folder(root: Path, n: int = 3, matrix: object | None = None, **extra) -> Path:
    (root / "depth").mkdir(parents=True)
    (root / "color").mkdir()
    for k in range(n):
        cv2.imwrite(str(root / "depth" / f"{k:06d}.png"), depth_mm(k))
        cv2.imwrite(str(root / "color" / f"{k:06d}.png"), colour(k))
    intr = {"width": W, "height": H, "intrinsic_matrix": matrix or [FX, 0, 0, 0, FY, 0, CX, CY, 1], **extra}
    (root / "camera_intrinsic.json").write_text(json.dumps(intr))
    return root


def test_open3d_layout_depth_round_trips(tmp_path: Path) -> None:
    folder = open3d_folder(tmp_path / "o3d")
    with open_source(f"depthpng:{folder}") as src:
        assert (src.info.width, src.info.height, src.info.extra["frames"]) == (W, H, 3)
        frames = [src.read() for _ in range(3)]
        with pytest.raises(EndOfRecording, match="loop=1"):
            src.read()
    for k, f in enumerate(frames):
        cam = f.camera
        assert (cam.fx, cam.fy, cam.cx, cam.cy) == (FX, FY, CX, CY)
        assert f.baseline_m == DEFAULT_BASELINE_M and f.doffs == 0.0
        assert np.array_equal(f.image, colour(k))
        z_true = depth_mm(k) / 1000.0
        z = f.depth()
        assert np.array_equal(np.isnan(z), z_true == 0)
        ok = z_true > 0
        assert np.max(np.abs(z[ok] - z_true[ok]) / z_true[ok]) < 1e-6  # Z round-trips through disparity
        assert np.allclose(f.disparity[ok], FX * DEFAULT_BASELINE_M / z_true[ok], rtol=1e-6)


def test_zed_flat_layout_with_baseline_and_loop(tmp_path: Path) -> None:
    root = tmp_path / "zed"
    root.mkdir()
    for k in range(2):
        cv2.imwrite(str(root / f"depth{k:06d}.png"), depth_mm(k))
        cv2.imwrite(str(root / f"left{k:06d}.png"), colour(k))
    (root / "intrinsics.json").write_text(json.dumps({"fx": FX, "fy": FY, "cx": CX, "cy": CY, "baseline_m": 0.12, "depth_scale": 1000, "fps": 15}))
    with open_source(f"depthpng:{root}?loop=1") as src:
        got = [src.read() for _ in range(3)]
    assert got[0].baseline_m == 0.12 and [g.meta["file"] for g in got] == ["depth000000.png", "depth000001.png", "depth000000.png"]
    assert got[1].timestamp == pytest.approx(1 / 15)
    ok = depth_mm(1) > 0
    assert np.allclose(got[1].disparity[ok], FX * 0.12 / (depth_mm(1)[ok] / 1000.0), rtol=1e-6)
    with open_source(f"depthpng:{root}?baseline=0.05&depth_scale=100") as src:
        f = src.read()
    ok0 = depth_mm(0) > 0
    assert f.baseline_m == 0.05 and np.allclose(f.depth()[ok0], depth_mm(0)[ok0] / 100.0, rtol=1e-6)


def test_row_major_matrix_and_depth_only(tmp_path: Path) -> None:
    root = tmp_path / "only"
    (root / "depth").mkdir(parents=True)
    cv2.imwrite(str(root / "depth" / "a.png"), depth_mm(0))
    (root / "cam.json").write_text(json.dumps({"intrinsic_matrix": [[FX, 0, CX], [0, FY, CY], [0, 0, 1]]}))
    with open_source(f"depthpng:{root}") as src:
        f = src.read()
    assert (f.camera.fx, f.camera.cx, f.camera.cy) == (FX, CX, CY)
    assert f.meta["image"] == "depth-visualisation" and f.image.shape == (H, W, 3)
    nearest = np.unravel_index(np.argmin(np.where(depth_mm(0) > 0, depth_mm(0), 65535)), (H, W))
    assert f.image[nearest][0] == 255 and f.image[depth_mm(0) == 0].max() == 0


def test_recorded_and_replayed(tmp_path: Path) -> None:
    folder = open3d_folder(tmp_path / "o3d", n=2)
    with open_source(f"depthpng:{folder}") as src:
        frames = [src.read(), src.read()]
        with RecordingWriter(tmp_path / "rec", src.info) as w:
            for f in frames:
                w.write(f)
    rec = open_recording(tmp_path / "rec")
    for k, f in enumerate(frames):
        g = rec.frame(k)
        assert np.array_equal(g.image, f.image)
        assert np.array_equal(np.isnan(g.disparity), np.isnan(f.disparity))
        assert np.nanmax(np.abs(g.disparity - f.disparity)) <= 1 / 128


def test_bad_folders(tmp_path: Path) -> None:
    with pytest.raises(SourceNotFound, match="not a folder"):
        open_source(f"depthpng:{tmp_path / 'nope'}")
    with pytest.raises(SourceError, match="unknown depthpng option"):
        open_source(f"depthpng:{tmp_path}?scale=2")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SourceNotFound, match="no depth PNGs"):
        open_source(f"depthpng:{tmp_path / 'empty'}")

    folder = open3d_folder(tmp_path / "nojson")
    (folder / "camera_intrinsic.json").unlink()
    with pytest.raises(CalibrationError, match="no intrinsics JSON"):
        open_source(f"depthpng:{folder}")

    folder = open3d_folder(tmp_path / "size", **{"width": 640})
    with pytest.raises(CalibrationError, match="640x60 camera"):
        open_source(f"depthpng:{folder}")

    folder = open3d_folder(tmp_path / "count")
    (folder / "color" / "000002.png").unlink()
    with pytest.raises(RecordingError, match="3 depth and 2 colour"):
        open_source(f"depthpng:{folder}")

    folder = open3d_folder(tmp_path / "eight")
    victim = folder / "depth" / "000000.png"
    cv2.imwrite(str(victim), (depth_mm(0) // 256).astype(np.uint8))
    with pytest.raises(RecordingError, match="16-bit") as exc:
        open_source(f"depthpng:{folder}")
    assert str(victim) in str(exc.value)

    folder = open3d_folder(tmp_path / "corrupt")
    victim = folder / "depth" / "000001.png"
    victim.write_bytes(b"garbage")
    with open_source(f"depthpng:{folder}") as src:
        assert src.read().meta["file"] == "000000.png"
        assert src.read().meta["file"] == "000002.png"  # the damaged one is skipped, the others still read
        assert str(victim) in src.warnings[0]
        with pytest.raises(RecordingError) as exc:
            src.frame(1)  # read directly, it says what is wrong
        assert str(victim) in str(exc.value)


def test_a_corrupt_image_is_skipped_per_pass_and_an_all_corrupt_folder_ends(tmp_path: Path) -> None:
    """One corrupt colour PNG among 4: played past, once per pass with loop=1; a folder whose every depth
    PNG after the first is unreadable (the first is read at open) ends in one read with loop=1 too."""
    from device import SourceEnded

    folder = open3d_folder(tmp_path / "o3d", n=4)
    (folder / "color" / "000002.png").write_bytes(b"not a png")
    with open_source(f"depthpng:{folder}") as src:
        assert [src.read().meta["frame_index"] for _ in range(3)] == [0, 1, 3]
        with pytest.raises(EndOfRecording, match=r"1 damaged frame\(s\) skipped in this pass: 2"):
            src.read()
    with open_source(f"depthpng:{folder}?loop=1") as src:
        assert [src.read().meta["frame_index"] for _ in range(3 * 10)] == [0, 1, 3] * 10
        assert src.playback.skipped_total == 10 and list(src.playback.skipped) == [2]
        assert "000002.png" in src.warnings[-1]
    bad = open3d_folder(tmp_path / "bad", n=3)
    with open_source(f"depthpng:{bad}?loop=1") as src:
        for png in (bad / "depth").glob("*.png"):
            png.write_bytes(b"\x89PNG truncated")
        with pytest.raises(SourceEnded, match="no frame of the depth folder .* can be read"):
            src.read()
