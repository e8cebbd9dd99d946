"""The cluster recipe of docs/batch.md on loopback: a Ray head and a second Ray node on this machine
(`ray start --head`, `ray start --address`), `depthruler batch --ray HEAD`, the second node killed
mid-run; the results are complete (one row per task) and equal to a local run.

The table has DEPTHRULER_CLUSTER_TASKS tasks (default 400 to fit CI on two cores: the node is killed
once two groups are written, with the others in flight or to come; the scale run of the issue is 50,000)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from batch_tables import HEADER, invoke, stable, truth

pytestmark = pytest.mark.slow
RAY = Path(sys.executable).with_name("ray")
# How soon the head declares a node that stopped answering dead: Ray's default (a check every 3 s, dead
# after 5 failed) kept the run waiting up to 15 s for the killed node's partitions to go to the head;
# here 1 s. A killed node's checks fail at once; a live one still has Ray's default timeout to answer
# each. What the run then does (the lost partitions measured again, each task's row once) is unchanged.
HEALTH_CHECK = {"health_check_period_ms": 500, "health_check_failure_threshold": 2}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _node_ip() -> str:
    """The address Ray's nodes bind to here (Ray picks the host's primary address, not loopback)."""
    from ray._private.services import get_node_ip_address

    return get_node_ip_address()


def _table(path: Path, archive: Path, n: int) -> Path:
    import csv

    rows = []
    for name in ("rec_poster", "rec_tilted"):
        for i in range(4):
            t = truth(archive / name, i)
            (x1, y1), (x2, y2) = t["p1_px"], t["p2_px"]
            rows.append((str(archive / name), i, x1, y1, x2, y2))
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        for k in range(n):
            src, i, x1, y1, x2, y2 = rows[k % len(rows)]
            d = (k // len(rows)) % 7  # clicks moved along the segment: every task a different measurement
            w.writerow([src, i, x1 + d, y1, x2 - d, y2, "robust", f"t{k}"])
    return path


@pytest.fixture
def cluster(tmp_path):
    """A head (1 CPU) and a worker node (1 CPU) on loopback, each `ray start --block` in a session of
    its own so that killing one kills its raylet and workers; both stopped at the end."""
    port = _free_port()
    token = os.urandom(16).hex()  # the recipe's shared token, here in the environment of every node
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": token}
    # no log monitor: the driver shows no worker logs (log_to_driver=False), nothing reads them
    common = ["--num-cpus", "1", "--disable-usage-stats", "--include-log-monitor", "false", "--block"]
    logs = tmp_path / "ray-logs"
    logs.mkdir()
    head = subprocess.Popen([str(RAY), "start", "--head", "--port", str(port), "--include-dashboard", "false",
                             "--system-config", json.dumps(HEALTH_CHECK), *common], env=env, start_new_session=True,
                            stdout=(logs / "head.out").open("w"), stderr=subprocess.STDOUT)  # fmt: skip
    address = f"{_node_ip()}:{port}"
    # started with the head, not after it: `ray start --address` waits for the head's GCS itself
    node = subprocess.Popen([str(RAY), "start", "--address", address, *common],
                            env=env, start_new_session=True, stdout=(logs / "node.out").open("w"), stderr=subprocess.STDOUT)  # fmt: skip
    _wait_started({"head": head, "node": node}, logs)
    yield address, node, token
    for proc in (node, head):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()


def _wait_started(procs: dict[str, subprocess.Popen], logs: Path, timeout: float = 180.0) -> None:
    """Until each `ray start` has printed "Ray runtime started.", which it does once its node is
    registered with the head (a node's start waits for that): no driver process, whose Python start
    and import of Ray cost seconds, polling the cluster for live nodes."""
    end = time.monotonic() + timeout
    waiting = dict(procs)
    while waiting and time.monotonic() < end:
        for name, proc in list(waiting.items()):
            if "Ray runtime started." in (logs / f"{name}.out").read_text(errors="replace"):
                del waiting[name]
            elif proc.poll() is not None:
                raise AssertionError(f"`ray start` of the {name} ended: " + (logs / f"{name}.out").read_text(errors="replace")[-2000:])
        time.sleep(0.1)
    if waiting:
        raise AssertionError(f"the Ray {', '.join(waiting)} did not start in {timeout} s: "
                             + " ".join((logs / f"{name}.out").read_text(errors="replace")[-1000:] for name in waiting))


def test_two_node_cluster_survives_a_killed_node(archive, tmp_path, cluster):
    address, node, token = cluster
    n = int(os.environ.get("DEPTHRULER_CLUSTER_TASKS", "400"))
    table = _table(tmp_path / "tasks.csv", archive, n)
    local = tmp_path / "local.parquet"
    invoke(["batch", str(table), "--out", str(local), "--workers", "1"])  # the local run, in this process
    out = tmp_path / "cluster.parquet"
    proc = subprocess.Popen([sys.executable, "-m", "cli.main", "batch", str(table), "--out", str(out), "--ray", address],
                            # the driver holds the token but chose no mode, as after copying ~/.ray/auth_token
                            env={**{k: v for k, v in os.environ.items() if k != "RAY_AUTH_MODE"}, "RAY_USAGE_STATS_ENABLED": "0",
                                 "RAY_AUTH_TOKEN": token, "PYTHONPATH": str(Path(__file__).resolve().parents[2])},
                            stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)  # fmt: skip
    parts = out.with_name(out.name + ".parts")
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and proc.poll() is None and len(list(parts.glob("part-*.parquet"))) < 2:
        time.sleep(0.2)
    assert proc.poll() is None, "the run ended before the node could be killed: " + (proc.stdout.read() if proc.stdout else "")
    done_before_kill = len(list(parts.glob("part-*.parquet")))
    os.killpg(node.pid, signal.SIGKILL)  # the second node, its raylet and its workers, mid-run
    print(f"node killed with {done_before_kill} group(s) written")
    output, _ = proc.communicate(timeout=900)
    assert proc.returncode == 0, output
    assert "on Ray (2 CPUs on 2 node(s)" in " ".join(output.split()), output  # the run began on both nodes
    assert f"{n} tasks measured" in output
    rows = pq.read_table(out).column("task").to_pylist()
    assert rows == list(range(n))  # exactly one row per task, none lost, none twice
    assert stable(out) == stable(local)
    shutil.rmtree(parts, ignore_errors=True)
