"""Host-built DepthAI objects for the OAK tests (no device): the calibration fixture and ImgFrames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import device.sources.oak  # noqa: F401  (sets DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT before depthai loads)
import depthai as dai  # noqa: E402

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "oak_calib.json"
A, B, C = dai.CameraBoardSocket.CAM_A, dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C


def fixture_camera(socket: int) -> dict:
    data = json.loads(FIXTURE.read_text())
    return next(cam for sock, cam in data["cameraData"] if sock == socket)


def img(arr: np.ndarray, kind) -> dai.ImgFrame:
    f = dai.ImgFrame()
    f.setCvFrame(arr, kind)
    return f
