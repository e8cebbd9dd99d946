"""Named stopping points of a batch run, for tests of crash recovery.

With ``DEPTHRULER_BATCH_STOP_AT=POINT`` (or ``POINT:N``, the N-th time it is reached) the process
kills itself with SIGKILL when it reaches that point, as a power cut or the OOM killer would: no
handler, no clean-up. Unset, :func:`reached` is one dictionary lookup. The points, in run order:

- ``opened``: the results store is open (stale temporary files removed), nothing written yet;
- ``part-tmp``: a group's part is on disk under its temporary name, not yet renamed;
- ``part``: a group's part is durable under its final name;
- ``merged``: the merged file is whole on disk under its temporary name;
- ``sealed``: the parts folder is renamed to ``.merged`` (the commit point);
- ``committed``: the merged file is renamed onto the results file;
- ``cleaning``: one file of the ``.merged`` folder is removed, the others not yet.
"""

from __future__ import annotations

import os
import signal

STOP_ENV = "DEPTHRULER_BATCH_STOP_AT"
POINTS = ("opened", "part-tmp", "part", "merged", "sealed", "committed", "cleaning")


def reached(point: str, count: int = 1) -> None:
    """Kill this process if ``STOP_ENV`` names ``point`` (and, with ``:N``, ``count == N``)."""
    want = os.environ.get(STOP_ENV)
    if not want:
        return
    name, _, n = want.partition(":")
    if name == point and (not n or int(n) == count):
        os.kill(os.getpid(), signal.SIGKILL)
