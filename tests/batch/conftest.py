"""Fixtures of the batch tests: a small simulated archive, a recording of shape scenes, one Ray instance per session
(joined in this process, and by address by a `depthruler batch` driver in a process of its own)."""

from __future__ import annotations

from pathlib import Path

import pytest

from batch_tables import SIZE, invoke


@pytest.fixture(scope="session")
def archive(tmp_path_factory) -> Path:
    """Two recordings made by `depthruler record` from the simulator, and their clicks (the truth's)."""
    root = tmp_path_factory.mktemp("archive")
    invoke(["record", "--source", f"sim:poster?fps=0&distance=3&{SIZE}", "--out", str(root / "rec_poster"), "--frames", "4"])
    invoke(["record", "--source", f"sim:poster?fps=0&distance=4.5&target=poster-length&yaw=15&lighting=mixed&seed=3&{SIZE}", "--out", str(root / "rec_tilted"), "--frames", "4"])
    return root


@pytest.fixture(scope="session")
def shape_rec(tmp_path_factory):
    """A recording of two simulated shape scenes (480x270): frame 0 a box on the floor, frame 1 a
    framed panel on a wall; with the cases that made them (their truth and clicks)."""
    from device import SourceInfo
    from device.formats.recording import RecordingWriter
    from sim.shapes import box_case, panel_case

    box = box_case(1, range_m=1.0, variant="plain", width=480, height=270)
    panel = panel_case(2, range_m=1.2, width=480, height=270)
    path = tmp_path_factory.mktemp("shapes") / "rec_shapes"
    with RecordingWriter(path, SourceInfo(kind="sim", name="shapes", width=480, height=270)) as w:
        w.write(box.frame)
        w.write(panel.frame)
    return path, box, panel


@pytest.fixture(scope="session")
def ray_session():
    """One local Ray instance with 2 CPUs for the whole session (starting Ray costs seconds), started
    as ``depthruler batch --ray local --workers 2`` starts its own (:class:`batch.executors.RayExecutor`:
    never a Ray another program runs here; idle worker processes kept, where Ray's default kills one
    idle for 1 s and the next task waits for a new process and its imports)."""
    import ray

    from batch.executors import make_executor

    assert not ray.is_initialized()
    executor = make_executor(2, "local")
    assert executor.describe() == "on Ray (2 CPUs on 1 node(s), 2 workers)"
    yield ray
    executor.close()
    assert not ray.is_initialized()


@pytest.fixture(scope="session")
def ray_address(ray_session) -> str:
    """The session's Ray instance's address, for a `depthruler batch --ray ADDRESS` driver in a process
    of its own: the driver joins it instead of starting a private Ray (seconds of a test's wall time
    per start), as a driver joins a cluster. Workers of a joining driver have the environment this
    process had when Ray started, not the driver's."""
    return ray_session.get_runtime_context().gcs_address
