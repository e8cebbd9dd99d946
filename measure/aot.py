"""The measuring kernels built ahead of time for this machine (docs/decisions/service-memory.md).

:func:`prepare` (``measure.warm_up`` calls it first) finds the extension module built for these
sources, this numba and this CPU in the cache, or builds it in a subprocess, and makes it this
process's kernels (:mod:`measure.compiled`); when it cannot (no C compiler, no Python headers, a numba
without ``numba.pycc``), the process keeps numba's just-in-time kernels and :data:`LAST_ERROR` says why.

The build (``python -m measure.aot --out DIR``) measures :func:`measure.warm_up`'s frames with the
just-in-time kernels, so every array type a measurement passes a kernel is compiled, and exports each
of those versions of each kernel of ``measure.compiled.KERNELS`` from one module, compiled by numba's
ahead-of-time compiler for the CPU the just-in-time kernels target (its name and its features), with a
manifest of each version's argument types. The cache is ``$DEPTHRULER_CACHE_DIR``, else
``measure/__pycache__/aot`` beside numba's cache when it can be written, else ``~/.cache/depthruler/aot``.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.metadata
import json
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

from measure import compiled

PACKAGE = Path(__file__).resolve().parent
BUILD_TIMEOUT_S = 900.0
KEEP_BUILDS = 4  # builds kept in the cache (the newest): one per recent version of the sources
LAST_ERROR = ""  # why the last prepare() kept the just-in-time kernels ("" when it did not)


def cache_root() -> Path:
    """Where built modules are kept (see the module docstring)."""
    if os.environ.get("DEPTHRULER_CACHE_DIR"):
        return Path(os.environ["DEPTHRULER_CACHE_DIR"]) / "aot"
    beside = PACKAGE / "__pycache__" / "aot"
    try:
        beside.mkdir(parents=True, exist_ok=True)
        if os.access(beside, os.W_OK):
            return beside
    except OSError:
        pass
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "depthruler" / "aot"


def _cpu() -> str:
    """The CPU's model and feature flags (what the code was built for), read without loading LLVM."""
    try:
        info = Path("/proc/cpuinfo").read_text().split("\n\n")[0]
        return "\n".join(line for line in info.splitlines() if line.startswith(("model name", "flags")))
    except OSError:
        return platform.processor() or platform.machine()


def key() -> str:
    """What a built module depends on: every source of ``measure`` (they fix the array types the
    kernels are given), numba's, llvmlite's and numpy's versions, Python's ABI and the CPU."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE.glob("*.py")):
        h.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    versions = [importlib.metadata.version(p) for p in ("numba", "llvmlite", "numpy")]
    for part in (*versions, sysconfig.get_config_var("EXT_SUFFIX") or "", sys.version, _cpu()):
        h.update(str(part).encode() + b"\0")
    return h.hexdigest()[:20]


def _is_built(folder: Path) -> bool:
    """Whether ``folder`` holds a finished build (its manifest is written last, before the rename)."""
    return (folder / compiled.MANIFEST).is_file()


def find_built() -> Path | None:
    """The folder of the module built for :func:`key`, or None."""
    folder = cache_root() / key()
    return folder if _is_built(folder) else None


def prepare(build_missing: bool = True) -> str:
    """Choose this process's kernels before its first measurement: the module built for this machine,
    built first (in a subprocess, about half a minute) when ``build_missing`` and it is not; else numba's.
    Returns where they come from: ``"aot: <folder>"``, or ``"jit"`` (``"jit: <why>"`` when the build
    was wanted and could not be made or loaded)."""
    global LAST_ERROR
    LAST_ERROR = ""
    if compiled.mode() == "jit":
        compiled.use(compiled.Kernels({}, "jit"))
        return "jit"
    target = cache_root() / key()
    folder = target if _is_built(target) else _build_in_subprocess(target) if build_missing else None
    if folder is not None:
        try:
            compiled.use(compiled.load_aot(folder))
            return compiled.active().origin
        except (ImportError, OSError, KeyError, ValueError) as exc:
            LAST_ERROR = f"the kernels built in {folder} do not load: {exc}"
    elif not LAST_ERROR:
        LAST_ERROR = "no kernels are built for this machine"
    if compiled.mode() == "aot":
        raise RuntimeError(f"DEPTHRULER_KERNELS=aot: {LAST_ERROR}")
    compiled.use(compiled.Kernels({}, "jit"))
    return f"jit: {LAST_ERROR}"


def _build_in_subprocess(folder: Path) -> Path | None:
    """``python -m measure.aot --out FOLDER`` on these sources; the folder, or None (LAST_ERROR says why)."""
    global LAST_ERROR
    env = {**os.environ, "DEPTHRULER_KERNELS": "jit",
           "PYTHONPATH": os.pathsep.join(p for p in (str(PACKAGE.parent), os.environ.get("PYTHONPATH", "")) if p)}  # fmt: skip
    try:
        done = subprocess.run([sys.executable, "-m", "measure.aot", "--out", str(folder)], env=env,
                              capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)  # fmt: skip
    except (OSError, subprocess.TimeoutExpired) as exc:
        LAST_ERROR = f"building the kernels ahead of time failed: {exc}"
        return None
    if done.returncode != 0 or not _is_built(folder):
        lines = (done.stderr or done.stdout).strip().splitlines() or ["no output"]
        cause = next((line for line in reversed(lines) if "Error" in line), lines[-1])  # the exception, not a hint after it
        LAST_ERROR = f"building the kernels ahead of time failed (exit {done.returncode}): {cause.strip()}"
        return None
    return folder


def _arg(t: object) -> dict:
    """A manifest entry for one argument type of a compiled version (numba's type)."""
    from numba.core import types

    if isinstance(t, types.Array):
        return {"kind": "array", "dtype": str(t.dtype), "ndim": t.ndim, "layout": t.layout, "readonly": not t.mutable}
    return {"kind": "scalar", "type": "bool" if t == types.boolean else str(t)}


def _forwarder(dispatcher: object, n: int):
    """A function of ``n`` arguments that calls ``dispatcher``: exported, it keeps the kernel's own
    compile options (error model, fast-math flags), which an exported kernel body would not."""
    names = ", ".join(f"a{i}" for i in range(n))
    namespace = {"kernel": dispatcher}
    exec(f"def forward({names}):\n    return kernel({names})", namespace)  # noqa: S102 - argument names only
    return namespace["forward"]


def build(out: Path) -> None:
    """Build the module into ``out`` (in this process, with the just-in-time kernels; see the module docstring)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc is pending deprecation; the just-in-time kernels remain
        from numba.core import codegen
        from numba.pycc import CC, compiler

    from measure.warm_up import warm_up

    warm_up()
    # The ahead-of-time code generator takes the features the CPU's name implies; the just-in-time one
    # asks the CPU. On a virtual machine they differ, and code for an implied feature the CPU lacks
    # would not run: give it the features the just-in-time kernels are compiled for.
    codegen.AOTCPUCodegen._customize_tm_features = lambda self: self._get_host_cpu_features()
    # Exported functions release the interpreter's lock while they run, as the just-in-time kernels do
    # (``nogil=True``): the service's event loop and capture thread run beside two measuring threads.
    plain_flags = compiler.Flags

    def flags_releasing_the_lock():
        flags = plain_flags()
        flags.release_gil = True
        return flags

    compiler.Flags = flags_releasing_the_lock
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=out.name + ".", dir=out.parent))  # beside it: published by a rename
    try:
        cc = CC(compiled.MODULE_NAME)
        cc.output_dir = str(tmp)
        cc.target_cpu = "host"
        cc.verbose = False
        variants = []
        for name in compiled.KERNELS:
            dispatcher = compiled.jit(name)
            for i, (argtypes, result) in enumerate(dispatcher.overloads.items()):
                export = f"{name}__{i}"
                cc.export(export, result.signature)(_forwarder(dispatcher, len(argtypes)))
                variants.append({"kernel": name, "export": export, "args": [_arg(t) for t in argtypes]})
        cc.compile()
        (built,) = [p.name for p in tmp.iterdir() if p.name.startswith(compiled.MODULE_NAME)]
        manifest = {"file": built, "key": out.name, "numba": importlib.metadata.version("numba"), "variants": variants}
        (tmp / compiled.MANIFEST).write_text(json.dumps(manifest, indent=1))
        tmp.chmod(0o755)  # mkdtemp made it for its owner only; a shared cache is read by others
        try:
            tmp.rename(out)  # published whole: a reader sees the folder with its manifest or nothing
        except OSError:
            if not _is_built(out):
                raise  # not another build's finished folder
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    _prune(out)


def _prune(current: Path) -> None:
    """Remove all but the newest ``KEEP_BUILDS`` builds beside ``current`` (a process that loaded one
    keeps its mapping of the file)."""
    builds = sorted((p for p in current.parent.iterdir() if p != current and _is_built(p)),
                    key=lambda p: p.stat().st_mtime, reverse=True)  # fmt: skip
    for old in builds[KEEP_BUILDS - 1 :]:
        shutil.rmtree(old, ignore_errors=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Build the measuring kernels ahead of time into OUT.")
    parser.add_argument("--out", type=Path, required=True)
    build(parser.parse_args(argv).out)


if __name__ == "__main__":
    main()
