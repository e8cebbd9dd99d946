"""Child process of :mod:`bench.measure_baseline`: the measurement core of a reference revision (on
its PYTHONPATH), timed on request. Reads pickled requests from stdin, writes pickled replies to stdout:
("load", cases) with cases as (frame fields, p1, p2), then ("time", case index, method, repeats) ->
(CPU and wall ms per call, n x 2, and the distance in m or NaN), ("quit",) to end."""

from __future__ import annotations

import math
import pickle
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from measure import Frame, MeasureError, MeasureOptions, PinholeCamera, measure_distance


def _frame(fields: dict) -> Frame:
    fields = dict(fields, camera=PinholeCamera(**fields["camera"]))
    return Frame(**{k: v for k, v in fields.items() if k in Frame.__dataclass_fields__})


def main() -> None:
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    cases = []
    with threadpool_limits(1):
        while True:
            req = pickle.load(inp)
            if req[0] == "quit":
                return
            if req[0] == "load":
                cases = [(_frame(f), p1, p2) for f, p1, p2 in req[1]]
                # The bench's own process has made and freed whole frames, which raises glibc's mmap
                # threshold: its measurement-sized arrays then come from the heap, not fresh pages.
                # Freeing one frame-sized block here does the same (else this side pays page faults).
                np.ones(1 << 21).sum()
                reply = len(cases)
            else:
                _, i, method, repeats = req
                frame, p1, p2 = cases[i]
                opts = MeasureOptions(method=method)
                rows = []
                try:
                    dist = measure_distance(frame, p1, p2, opts).distance_m  # also the warm-up
                    for _ in range(repeats):
                        t0, c0 = time.perf_counter(), time.process_time()
                        measure_distance(frame, p1, p2, opts)
                        rows.append(((time.process_time() - c0) * 1e3, (time.perf_counter() - t0) * 1e3))
                except MeasureError:
                    dist = math.nan
                reply = (np.array(rows).reshape(-1, 2), dist)
            pickle.dump(reply, out)
            out.flush()


if __name__ == "__main__":
    main()
