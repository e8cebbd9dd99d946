"""Load the measuring core's compiled kernels before the first measurement that needs them.

First the kernels built ahead of time for this machine are chosen (:func:`measure.aot.prepare`: built
in a subprocess the first time, about half a minute, then loaded from the cache in a fraction of a
second), or numba's just-in-time kernels where they cannot be built. numba compiles each of its
kernels the first time it is called after an install (cached on disk) and loads it per array type,
so a process that measured once on a small frame would still load the kernels of a long segment
(over 600 samples FAST-MCD subsamples in single precision) or of a bent one inside a person's first
such click. :func:`warm_up` then measures synthetic frames that take every path a measurement takes
to a kernel (docs/decisions/core-speed.md); the ahead-of-time build exports the versions those
measurements compile.
"""

from __future__ import annotations

import numpy as np

from measure.distance import measure_distance
from measure.options import METHODS
from measure.types import Frame, MeasureError, MeasureOptions, PinholeCamera

_H, _W = 48, 720
_BASELINE_M = 0.1


def _profiles() -> dict[str, np.ndarray]:
    """Disparity (px) across the columns: a tilted wall, two walls at a crease, a nearer panel."""
    u = np.arange(_W, dtype=np.float64) / _W
    return {
        "tilted wall": 8.0 + 4.0 * u,
        "crease": 8.0 + 6.0 * np.abs(u - 0.5),
        "panel": np.where(np.abs(u - 0.5) < 0.15, 16.0, 8.0 + 4.0 * u),
    }


def warm_up(seed: int = 0) -> str:
    """Choose the kernels (:func:`measure.aot.prepare`), then measure each profile of :func:`_profiles`
    (1/4 px steps, 0.15 px noise, 5 % outliers) by every method along a short segment and one of 700 px
    (``seed`` draws the noise). Returns where the kernels come from: ``"aot: <folder>"``, or ``"jit"``
    (``"jit: <why>"`` when building them ahead of time failed)."""
    from measure.aot import prepare

    origin = prepare()
    rng = np.random.default_rng(seed)
    camera = PinholeCamera(fx=float(_W), fy=float(_W), cx=(_W - 1) / 2, cy=(_H - 1) / 2, width=_W, height=_H)
    image = np.zeros((_H, _W, 3), np.uint8)
    y = _H / 2
    for profile in _profiles().values():
        d = np.tile(profile, (_H, 1)) + rng.normal(0.0, 0.15, (_H, _W))
        wrong = rng.random((_H, _W)) < 0.05
        d[wrong] *= rng.uniform(0.5, 1.5, int(wrong.sum()))
        frame = Frame(image=image, disparity=(np.round(d * 4.0) / 4.0).astype(np.float32), camera=camera, baseline_m=_BASELINE_M)
        for method in METHODS:
            for x2 in (80.0, _W - 10.0):
                try:
                    measure_distance(frame, (10.0, y), (x2, y), MeasureOptions(method=method))
                except MeasureError:
                    pass  # a refusal took its kernels as far as it went
    return origin
