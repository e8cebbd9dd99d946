"""Task tables and recordings on object storage or a shared filesystem, through fsspec URLs.

A URL is ``SCHEME://...`` with a scheme fsspec knows (``s3://``, ``gs://``, ``az://``, ``file://``,
...). A task table at a URL is read through fsspec; a recording at a URL is copied once per worker
machine into a local cache (``$DEPTHRULER_CACHE`` or ``~/.cache/depthruler/recordings``) and read
from there with the normal reader, so the measurements are those of the local run. The cache entry
is named by the URL and a digest of the remote listing (names, sizes, ETags or mtimes): a recording
changed on the store is fetched again, never read stale. A copy is made in a temporary folder and
renamed into place, so a worker killed mid-copy leaves nothing that a later run would trust.

Credentials and endpoints come from the filesystem's usual configuration (for S3:
``AWS_ACCESS_KEY_ID``/``AWS_SECRET_ACCESS_KEY`` or a profile, ``AWS_ENDPOINT_URL`` for an
S3-compatible server such as MinIO).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

from batch.tasks import TaskError

LOCAL_SCHEMES = ("file", "local")


def is_url(text: str) -> bool:
    """``text`` names a location through an fsspec protocol (not a local path or a source spec)."""
    scheme, sep, rest = text.partition("://")
    if not sep or len(scheme) < 2 or not scheme.replace("+", "").replace("-", "").isalnum():
        return False
    from fsspec.registry import known_implementations, registry

    return scheme.lower() in known_implementations or scheme.lower() in registry


def _fs(url: str):
    import fsspec

    try:
        fs, path = fsspec.core.url_to_fs(url)
    except (ImportError, ValueError) as exc:
        raise TaskError(f"{url}: cannot use this storage ({exc}); install its fsspec driver, e.g. pip install 'depthruler[remote]'") from exc
    return fs, path


def join(base: str, relative: str) -> str:
    """``relative`` (a table cell) resolved against the URL of the table's folder ``base``."""
    return base.rstrip("/") + "/" + relative.lstrip("./")


def parent(url: str) -> str:
    return url.rsplit("/", 1)[0] if "/" in url.partition("://")[2] else url


def fetch_table(url: str, folder: Path) -> Path:
    """A local copy (in ``folder``) of the task table at ``url``, keeping its suffix."""
    fs, path = _fs(url)
    local = folder / ("table" + Path(path).suffix.lower())
    try:
        fs.get_file(path, str(local))
    except FileNotFoundError:
        raise TaskError(f"{url} does not exist; give the URL of a CSV, JSONL or Parquet table of tasks") from None
    except Exception as exc:  # noqa: BLE001 — each storage driver raises its own types (botocore, google, ...)
        raise TaskError(f"{url} cannot be read ({exc}); check the address and the credentials") from exc
    return local


def cache_root() -> Path:
    return Path(os.environ.get("DEPTHRULER_CACHE") or Path.home() / ".cache" / "depthruler") / "recordings"


def local_recording(url: str) -> Path:
    """The local cache folder holding the recording at ``url``, fetched if not there yet."""
    fs, path = _fs(url)
    try:
        listing = fs.find(path, detail=True)
    except Exception as exc:  # noqa: BLE001 — as in fetch_table
        raise TaskError(f"recording {url} cannot be listed ({exc}); check the address and the credentials") from exc
    if not listing:
        raise TaskError(f"recording {url} holds no files; give the URL of a folder written by `depthruler record`")
    prefix = path.rstrip("/") + "/"
    entries = sorted(
        (name[len(prefix):], info.get("size"), str(info.get("ETag") or info.get("etag") or info.get("mtime") or info.get("LastModified")))
        for name, info in listing.items() if name.startswith(prefix)
    )  # fmt: skip
    digest = hashlib.sha256(json.dumps([url, entries], default=str).encode()).hexdigest()[:20]
    target = cache_root() / digest
    if target.is_dir():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".fetch-", dir=target.parent))
    try:
        for rel, _, _ in entries:
            dest = tmp / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            fs.get_file(prefix + rel, str(dest))
        try:
            tmp.rename(target)
        except OSError:  # another worker of this machine finished the same copy first
            if not target.is_dir():
                raise
    except Exception as exc:  # noqa: BLE001 — as in fetch_table
        raise TaskError(f"recording {url} cannot be copied to {target.parent} ({exc}); free disk space or set DEPTHRULER_CACHE") from exc
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return target
