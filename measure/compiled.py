"""The measuring core's compiled kernels, as the rest of ``measure`` calls them: machine code built
ahead of time for this machine (:mod:`measure.aot`) when it is in the cache, else numba's
just-in-time kernels (``measure.kernels``, ``measure.fit_kernels``, ``measure.mcd_kernels``).

The ahead-of-time module is the same numba kernels compiled into an extension module for this CPU:
the same answers bit for bit (tests/measure/test_aot.py), without LLVM and numba's runtime in the
process (docs/decisions/service-memory.md). Its functions do not check what they are given, so every
call is checked here against the types the module was built for (dtype, dimensions, C order,
writability, alignment of each array); a call with other types goes to the just-in-time kernel, which
compiles for them. ``DEPTHRULER_KERNELS`` = ``jit`` or ``aot`` forces one (``auto``, the default, takes
the built module when there is one).
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

# The kernels the rest of measure calls from Python -> the module that defines them (their helpers
# are compiled into them).
KERNELS = {
    "median_1d": "measure.kernels",
    "lag_one_correlation": "measure.kernels",
    "moments_det_lam": "measure.kernels",
    "start_coefficients": "measure.kernels",
    "row_scales": "measure.kernels",
    "crease_candidates": "measure.kernels",
    "normalised": "measure.mcd_kernels",
    "start_moments": "measure.mcd_kernels",
    "masked_sums": "measure.mcd_kernels",
    "few_starts_step": "measure.mcd_kernels",
    "full_data_stage": "measure.mcd_kernels",
    "keep_best": "measure.mcd_kernels",
    "bisquare_location": "measure.fit_kernels",
    "robust_line": "measure.fit_kernels",
    "mcd_finish": "measure.fit_kernels",
}
MODES = ("auto", "aot", "jit")
MODULE_NAME = "_depthruler_kernels"  # the extension module's name (measure.aot builds it)
MANIFEST = "manifest.json"


class Kernels:
    """One process's kernels: for each name, the ahead-of-time variants (a check of the arguments and
    the function) and the just-in-time fallback, looked up on first use."""

    def __init__(self, variants: dict[str, list[tuple[Callable[..., bool], Callable[..., Any]]]], origin: str) -> None:
        self.variants = variants
        self.origin = origin  # "aot: <folder>" or "jit"
        self.fallbacks: dict[str, int] = {}  # calls the ahead-of-time module had no variant for, by kernel
        self._jit: dict[str, Callable[..., Any]] = {}  # numba's dispatchers, looked up once each

    def call(self, name: str, args: tuple) -> Any:
        for check, fn in self.variants.get(name, ()):
            if check(*args):
                return fn(*args)
        if self.variants:
            self.fallbacks[name] = self.fallbacks.get(name, 0) + 1
        kernel = self._jit.get(name)
        if kernel is None:
            kernel = self._jit[name] = jit(name)
        return kernel(*args)


def jit(name: str) -> Callable[..., Any]:
    """The numba dispatcher of kernel ``name`` (numba is imported here, on first use)."""
    return getattr(importlib.import_module(KERNELS[name]), name)


def _array_check(spec: dict, i: int) -> str:
    """A Python expression true when argument ``a{i}`` is an array the variant was built for."""
    a = f"a{i}"
    terms = [f"type({a}) is ndarray", f"{a}.dtype == {spec['dtype']!r}", f"{a}.ndim == {spec['ndim']}"]
    flags = [f"{a}.flags.aligned"]
    if spec["layout"] == "C":
        flags.append(f"{a}.flags.c_contiguous")
    if not spec["readonly"]:
        flags.append(f"{a}.flags.writeable")
    return "(" + " and ".join(terms) + f" and ({' and '.join(flags)}))"


# What numba types as each scalar type (anything else it would compile another version for).
_SCALARS = {"float64": "float", "int64": "(int, np.int64)", "bool": "(bool, np.bool_)"}


def make_check(args: list[dict]) -> Callable[..., bool]:
    """The argument check of one ahead-of-time variant, from its manifest entry: each array's dtype,
    dimensions, order, writability and alignment, each scalar's type as numba would type it."""
    names = ", ".join(f"a{i}" for i in range(len(args)))
    terms = []
    for i, spec in enumerate(args):
        if spec["kind"] == "array":
            terms.append(_array_check(spec, i))
        elif spec["type"] in _SCALARS:
            not_bool = f" and type(a{i}) is not bool" if spec["type"] == "int64" else ""
            terms.append(f"(isinstance(a{i}, {_SCALARS[spec['type']]}){not_bool})")
        else:
            terms.append("False")  # a type this check does not know: never the ahead-of-time variant
    namespace: dict[str, Any] = {"ndarray": np.ndarray, "np": np}
    exec(f"def check({names}):\n    return {' and '.join(terms) or 'True'}", namespace)  # noqa: S102 - built from the manifest's type names
    return namespace["check"]


def load_aot(folder: Path) -> Kernels:
    """The kernels of the module built in ``folder`` (its manifest names each variant's argument types)."""
    manifest = json.loads((folder / MANIFEST).read_text())
    path = folder / manifest["file"]
    spec = importlib.util.spec_from_file_location(MODULE_NAME, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    variants: dict[str, list] = {}
    for entry in manifest["variants"]:
        variants.setdefault(entry["kernel"], []).append((make_check(entry["args"]), getattr(module, entry["export"])))
    return Kernels(variants, f"aot: {folder}")


_active: Kernels | None = None


def mode() -> str:
    value = os.environ.get("DEPTHRULER_KERNELS", "auto").strip().lower() or "auto"
    if value not in MODES:
        raise ValueError(f"DEPTHRULER_KERNELS={value!r}: use one of {', '.join(MODES)}")
    return value


def use(kernels: Kernels) -> None:
    """Make ``kernels`` this process's kernels (measure.aot.prepare, before the first measurement)."""
    global _active
    _active = kernels


def active() -> Kernels:
    """This process's kernels, chosen on first use (:func:`measure.aot.prepare`, without building):
    the built module for this machine when there is one (``auto``, ``aot``), else numba's."""
    if _active is None:
        from measure.aot import prepare

        prepare(build_missing=False)
    assert _active is not None  # prepare() chose them, or raised
    return _active


def _forward(name: str) -> Callable[..., Any]:
    def kernel(*args: Any) -> Any:
        return active().call(name, args)

    kernel.__name__ = kernel.__qualname__ = name
    kernel.__doc__ = f"``{KERNELS[name]}.{name}``, from this process's kernels (:func:`active`)."
    return kernel


# The kernels by their numba sources' names and arguments: ``from measure.compiled import median_1d``.
globals().update({name: _forward(name) for name in KERNELS})
__all__ = [*KERNELS, "KERNELS", "Kernels", "active", "jit", "load_aot", "make_check", "mode", "use"]
