"""Whether this machine can build the measuring kernels ahead of time (measure/aot.py): tests that
hold the built kernels skip, saying what is missing, where it cannot; where it can, a failed build
fails them."""

from __future__ import annotations

import os
import shlex
import shutil
import sysconfig
from pathlib import Path


def missing_build_tools() -> str:
    """What the build lacks here ("" when nothing): a C compiler, or Python's headers."""
    compiler = shlex.split(os.environ.get("CC") or "cc")[0]
    if shutil.which(compiler) is None:
        return f"no C compiler ({compiler}) to build the measuring kernels ahead of time"
    if not (Path(sysconfig.get_paths()["include"]) / "Python.h").is_file():
        return "no Python headers (Python.h) to build the measuring kernels ahead of time"
    return ""
