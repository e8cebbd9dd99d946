"""Batch on object storage: the task table and the recordings on an S3-compatible server on
loopback (moto in server mode), measured on a pool, equal to the same archive run from disk."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from batch_tables import depthruler, invoke, stable, write_tasks


@pytest.fixture
def s3(monkeypatch, tmp_path):
    """A bucket on a private moto S3 server; the environment points boto at it (as for MinIO)."""
    from moto import server as moto_server  # not at collection, which every worker pays

    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    for k, v in {"AWS_ACCESS_KEY_ID": "test", "AWS_SECRET_ACCESS_KEY": "test", "AWS_DEFAULT_REGION": "us-east-1",
                 "AWS_ENDPOINT_URL": f"http://{host}:{port}", "DEPTHRULER_CACHE": str(tmp_path / "cache")}.items():  # fmt: skip
        monkeypatch.setenv(k, v)
    import urllib.request

    import s3fs

    # moto keeps one in-process store for every server it starts: empty it
    urllib.request.urlopen(urllib.request.Request(f"http://{host}:{port}/moto-api/reset", method="POST")).close()

    s3fs.S3FileSystem.clear_instance_cache()  # a filesystem made for an earlier server keeps its endpoint
    fs = s3fs.S3FileSystem(skip_instance_cache=True)
    fs.mkdir("archive")
    yield fs
    server.stop()


# Where Ray's driver reads the job's configuration (what `ray job submit` sets for a submitted driver)
JOB_CONFIG = "RAY_JOB_CONFIG_JSON_ENV_VAR"
WHERE = {"source", "task_key", "error"}  # the error message names the recording's path or URL


def _archive_on_s3(archive, s3, tmp_path):
    """The two recordings and a table of 17 tasks (one on a frame not recorded) on disk and in the
    bucket; the local run's results."""
    local = tmp_path / "local"
    for name in ("rec_poster", "rec_tilted"):
        shutil.copytree(archive / name, local / name)
    table = write_tasks(local / "tasks.csv", local, methods=("robust",), extra_rows=[["rec_poster", 9, 10, 10, 100, 100, "robust", "missing"]])
    s3.put(str(local) + "/", "archive/", recursive=True)
    assert s3.exists("archive/rec_poster/recording.json") or s3.ls("archive/rec_poster")
    ref = tmp_path / "ref.parquet"
    invoke(["batch", str(table), "--out", str(ref), "--workers", "1"])
    return ref


def test_tasks_and_recordings_on_s3_give_the_local_rows(archive, s3, tmp_path):
    ref, got = _archive_on_s3(archive, s3, tmp_path), tmp_path / "s3.parquet"
    res = invoke(["batch", "s3://archive/tasks.csv", "--out", str(got), "--workers", "2"])
    assert "17 tasks measured (1 error rows)" in res
    want, have = stable(ref, drop=WHERE), stable(got, drop=WHERE)
    assert len(have) == 17 and have == want
    assert "frame 9 is not in" in stable(got)[16]["error"]
    assert {r["source"] for r in stable(got)} == {"replay:s3://archive/rec_poster", "replay:s3://archive/rec_tilted"}
    # a second run reads the cached copies; a recording changed on the store is fetched again
    cached = sorted(p.name for p in (tmp_path / "cache" / "recordings").iterdir())
    assert len(cached) == 2
    s3.rm("archive/rec_tilted", recursive=True)
    res = invoke(["batch", "s3://archive/tasks.csv", "--out", str(tmp_path / "again.parquet"), "--workers", "1"])
    errors = [r for r in stable(tmp_path / "again.parquet") if r["error"]]
    assert len(errors) == 1 + 8 and all("rec_tilted" in r["error"] or "frame 9" in r["error"] for r in errors)


@pytest.mark.slow
def test_on_ray_data_the_workers_read_table_and_recordings_from_s3(archive, s3, tmp_path, ray_address):
    """A driver joined to the session's Ray: a worker scans the table at its URL, Ray Data's read
    tasks parse it and the measuring workers fetch the recordings; the rows equal the local run's.
    The workers have the store's endpoint and keys in the job's environment (a runtime environment,
    given to the driver as `ray job submit --runtime-env-json` gives it), not the Ray's."""
    ref, got = _archive_on_s3(archive, s3, tmp_path), tmp_path / "s3.parquet"
    store_env = {k: os.environ[k] for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_DEFAULT_REGION", "AWS_ENDPOINT_URL", "DEPTHRULER_CACHE")}
    job = {"runtime_env": {"env_vars": store_env}}
    proc = depthruler(["batch", "s3://archive/tasks.csv", "--out", str(got), "--ray", ray_address], env={JOB_CONFIG: json.dumps(job)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "17 tasks measured (1 error rows)" in " ".join(proc.stdout.split())
    assert stable(got, drop=WHERE) == stable(ref, drop=WHERE)
    assert {r["source"] for r in stable(got)} == {"replay:s3://archive/rec_poster", "replay:s3://archive/rec_tilted"}


def test_a_missing_table_url_is_a_one_line_error(s3, tmp_path):
    from typer.testing import CliRunner

    from cli.main import app

    res = CliRunner().invoke(app, ["batch", "s3://archive/nope.csv", "--out", str(tmp_path / "r.parquet")])
    assert res.exit_code == 1 and "s3://archive/nope.csv does not exist" in res.output


def test_an_unreachable_store_is_a_one_line_error(monkeypatch, tmp_path):
    import socket

    from typer.testing import CliRunner

    import s3fs

    from cli.main import app

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    for k, v in {"AWS_ACCESS_KEY_ID": "test", "AWS_SECRET_ACCESS_KEY": "test", "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}",
                 "AWS_MAX_ATTEMPTS": "1"}.items():  # fmt: skip
        monkeypatch.setenv(k, v)
    s3fs.S3FileSystem.clear_instance_cache()
    res = CliRunner().invoke(app, ["batch", "s3://archive/tasks.csv", "--out", str(tmp_path / "r.parquet")])
    assert res.exit_code == 1 and "s3://archive/tasks.csv cannot be read" in res.output and "credentials" in res.output
    assert not list(tmp_path.iterdir())
