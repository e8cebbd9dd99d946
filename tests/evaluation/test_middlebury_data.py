"""`depthruler data fetch`: the eight Middlebury scenes from their two official archives, every file
checked against its recorded SHA-256; the tests skip with that command named when the data is absent."""

from __future__ import annotations

import functools
import http.server
import threading
import zipfile
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from evaluation.middlebury_data import ARCHIVE_DIR, ARCHIVES, FILES, SCENES, DataError, fetch, verify

ROOT = Path(__file__).resolve().parents[2]
pytest_plugins = ["pytester"]  # the skip test runs a pytest session of its own


@pytest.fixture(scope="module")
def archives(middlebury_dir, tmp_path_factory) -> Path:
    """The two archives laid out as the Middlebury site ships them, built from the scenes on disk."""
    out = tmp_path_factory.mktemp("zips")
    split = {ARCHIVES[0]: ("calib.txt", "im0.png", "im1.png"), ARCHIVES[1]: ("disp0GT.pfm", "mask0nocc.png")}
    for name, files in split.items():
        with zipfile.ZipFile(out / name, "w") as zf:
            for scene in SCENES:
                for f in files:
                    zf.write(middlebury_dir / scene / f, f"{ARCHIVE_DIR}/{scene}/{f}")
            zf.writestr(f"{ARCHIVE_DIR}/Jadeplant/calib.txt", "a scene the project does not use")
    return out


@pytest.fixture()
def server(archives):
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(archives))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()


def test_fetch_downloads_checks_and_places_every_scene(server, middlebury_dir, tmp_path):
    dest = tmp_path / "mb"
    res = CliRunner().invoke(app, ["data", "fetch", "--dest", str(dest), "--url", server])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in dest.iterdir()) == sorted(SCENES)  # no extra scene, no temporary folder left
    for scene in SCENES:
        for f in FILES:
            assert (dest / scene / f).read_bytes() == (middlebury_dir / scene / f).read_bytes()
    assert verify(dest) == []
    # a second fetch downloads nothing (the server is not even asked)
    assert "match their checksums" in " ".join(CliRunner().invoke(app, ["data", "fetch", "--dest", str(dest), "--url", "http://127.0.0.1:9"]).output.split())


def test_a_changed_file_is_fetched_again_and_a_damaged_archive_is_refused(server, archives, tmp_path):
    dest = tmp_path / "mb"
    fetch(dest, base_url=server)
    (dest / "Piano" / "im0.png").write_bytes(b"changed")
    assert verify(dest) == ["Piano/im0.png"]
    fetch(dest, archives_dir=archives)  # from archives on disk, no download
    assert verify(dest) == []
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / ARCHIVES[0]).write_bytes((archives / ARCHIVES[0]).read_bytes())
    with zipfile.ZipFile(bad / ARCHIVES[1], "w") as zf:
        zf.writestr(f"{ARCHIVE_DIR}/Teddy/disp0GT.pfm", b"Pf\n1 1\n-1\n\0\0\0\0")
    (dest / "Teddy" / "mask0nocc.png").unlink()
    with pytest.raises(DataError, match="Teddy: disp0GT.pfm, mask0nocc.png"):
        fetch(dest, archives_dir=bad)
    assert not (dest / "Teddy" / "disp0GT.pfm").read_bytes().startswith(b"Pf\n1 1")  # the scene in place was not touched


def test_an_unreachable_server_names_the_manual_way(tmp_path):
    res = CliRunner().invoke(app, ["data", "fetch", "--dest", str(tmp_path / "mb"), "--url", "http://127.0.0.1:9"])
    assert res.exit_code == 1 and "--from DIR" in res.output and "Traceback" not in res.output


def test_tests_that_need_the_scenes_skip_with_the_fetch_command(pytester, monkeypatch, tmp_path):
    # a pytest session of its own in this process (a second interpreter would import everything again);
    # timeout=0: its tests must not set or cancel the alarm pytest-timeout holds for this one
    monkeypatch.setenv("DEPTHRULER_SHARED", str(tmp_path / "nowhere"))
    res = pytester.runpytest_inprocess(str(ROOT / "tests" / "device" / "test_middlebury_io.py"), "-q", "-rs", "-p", "no:cacheprovider",
                                       "-o", "timeout=0", f"--rootdir={ROOT}", "-c", str(ROOT / "pyproject.toml"))  # fmt: skip
    out = res.stdout.str()
    assert res.ret == 0, out[-2000:]
    assert "SKIPPED" in out and "depthruler data fetch" in out and "failed" not in out
