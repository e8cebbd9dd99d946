"""The eight Middlebury 2014 scenes the evaluation and the tests use: where they are, and how to fetch them.

Scenes: Adirondack, Motorcycle, Piano, Pipes, Playroom, Recycle, Shelves, Teddy of the MiddEval3
training set at quarter resolution, each with ``im0.png``, ``im1.png``, ``calib.txt``,
``disp0GT.pfm`` and ``mask0nocc.png``. Every file's SHA-256 is recorded in
``evaluation/data/middlebury.sha256`` (``sha256sum -c`` reads it too).

Where: ``$DEPTHRULER_SHARED/data/middlebury`` when that variable is set; else
``../shared/data/middlebury`` beside the project when it exists; else ``data/middlebury`` inside the
project (where `depthruler data fetch` writes by default; ignored by git).

Fetching (:func:`fetch`): 1. download the two official archives (``MiddEval3-data-Q.zip``: images and
calibration; ``MiddEval3-GT0-Q.zip``: ground truth and masks) from ``base_url``; 2. take each scene's
five files out of ``MiddEval3/trainingQ/<scene>/``; 3. check every file against its recorded SHA-256;
4. move each complete scene into place (a scene is whole or absent). Nothing else is imported here, so
the tests' collection can ask where the data is cheaply.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import urllib.error
import urllib.request
import zipfile
from collections.abc import Callable
from pathlib import Path

BASE_URL = "https://vision.middlebury.edu/stereo/submit3/zip"
ARCHIVES = ("MiddEval3-data-Q.zip", "MiddEval3-GT0-Q.zip")
ARCHIVE_DIR = "MiddEval3/trainingQ"
SCENES = ("Adirondack", "Motorcycle", "Piano", "Pipes", "Playroom", "Recycle", "Shelves", "Teddy")
FILES = ("calib.txt", "disp0GT.pfm", "im0.png", "im1.png", "mask0nocc.png")
CHECKSUMS_FILE = Path(__file__).resolve().parent / "data" / "middlebury.sha256"
FETCH_COMMAND = "depthruler data fetch"
_PROJECT = Path(__file__).resolve().parents[1]


class DataError(RuntimeError):
    """The scenes cannot be fetched or do not match their checksums; the message says what to do."""


def checksums() -> dict[str, str]:
    """``"<scene>/<file>"`` -> SHA-256 hex digest of every file of every scene."""
    out = {}
    for line in CHECKSUMS_FILE.read_text().splitlines():
        digest, _, name = line.partition("  ")
        if digest:
            out[name.strip()] = digest
    return out


def default_data_dir() -> Path:
    """The folder that holds the scenes (see the module docstring for the order)."""
    if os.environ.get("DEPTHRULER_SHARED"):
        return Path(os.environ["DEPTHRULER_SHARED"]) / "data" / "middlebury"
    beside = _PROJECT.parent / "shared" / "data" / "middlebury"
    return beside if beside.is_dir() else _PROJECT / "data" / "middlebury"


def fetch_destination() -> Path:
    """Where :func:`fetch` writes when not told: the data folder in use, or the project's ``data/middlebury``."""
    found = default_data_dir()
    return found if os.environ.get("DEPTHRULER_SHARED") or found.is_dir() else _PROJECT / "data" / "middlebury"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def verify(data_dir: Path, scenes: tuple[str, ...] = SCENES) -> list[str]:
    """The ``scene/file`` names of ``scenes`` that are missing or differ from their checksum in ``data_dir``
    (empty: all good)."""
    sums = checksums()
    bad = []
    for name in (f"{s}/{f}" for s in scenes for f in FILES):
        path = Path(data_dir) / name
        if not path.is_file() or _sha256(path) != sums[name]:
            bad.append(name)
    return bad


def _download(url: str, to: Path, progress: Callable[[str], None]) -> None:
    progress(f"downloading {url}")
    try:
        with urllib.request.urlopen(url, timeout=60) as resp, open(to, "wb") as fh:
            shutil.copyfileobj(resp, fh, 1 << 20)
    except (urllib.error.URLError, OSError, ValueError) as exc:
        raise DataError(
            f"cannot download {url} ({exc}); download it by hand and run `{FETCH_COMMAND} --from DIR` on the folder "
            "that holds the two zip files, or set DEPTHRULER_SHARED to a folder with data/middlebury"
        ) from exc


def fetch(dest: Path | None = None, *, base_url: str = BASE_URL, archives_dir: Path | None = None,
          progress: Callable[[str], None] = lambda _m: None) -> Path:
    """Fetch the eight scenes into ``dest`` (default :func:`fetch_destination`) and check them; returns ``dest``.

    ``archives_dir``: a folder that already holds the two archives (nothing is downloaded). Scenes
    already present and matching their checksums are kept. Raises DataError naming what failed.
    """
    dest = Path(dest) if dest is not None else fetch_destination()
    sums = checksums()
    todo = [s for s in SCENES if verify(dest, (s,))]
    if not todo:
        progress(f"all {len(SCENES)} scenes in {dest} match their checksums")
        return dest
    dest.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=dest, prefix=".fetch-") as tmp:
        tmp_dir = Path(tmp)
        zips = []
        for name in ARCHIVES:
            local = Path(archives_dir) / name if archives_dir is not None else tmp_dir / name
            if archives_dir is None:
                _download(f"{base_url.rstrip('/')}/{name}", local, progress)
            elif not local.is_file():
                raise DataError(f"{local} is missing; put both {' and '.join(ARCHIVES)} in {archives_dir}")
            zips.append(local)
        staged = tmp_dir / "scenes"
        for z in zips:
            try:
                with zipfile.ZipFile(z) as zf:
                    for scene in todo:
                        for f in FILES:
                            member = f"{ARCHIVE_DIR}/{scene}/{f}"
                            if member in zf.namelist():
                                (staged / scene).mkdir(parents=True, exist_ok=True)
                                with zf.open(member) as src, open(staged / scene / f, "wb") as out:
                                    shutil.copyfileobj(src, out, 1 << 20)
            except zipfile.BadZipFile as exc:
                raise DataError(f"{z.name} is not a readable zip archive ({exc}); fetch it again") from exc
        for scene in todo:
            wrong = [f for f in FILES if not (staged / scene / f).is_file() or _sha256(staged / scene / f) != sums[f"{scene}/{f}"]]
            if wrong:
                raise DataError(f"{scene}: {', '.join(wrong)} missing from the archives or not matching the recorded "
                                f"SHA-256 ({CHECKSUMS_FILE.name}); the archives may be damaged or a different release")
        for scene in todo:
            target = dest / scene
            if target.exists():
                shutil.rmtree(target)
            os.replace(staged / scene, target)
            progress(f"{scene}: {len(FILES)} files checked")
    return dest

