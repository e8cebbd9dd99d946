"""What `depthruler doctor` found: one :class:`Finding` per check, and the :class:`DoctorReport` of a run."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

STATUSES = ("pass", "warn", "fail", "skip")  # skip: the check does not apply to this source (USB of a recording)


@dataclass(frozen=True)
class Finding:
    """One check's verdict: ``check`` (its name, e.g. "fps"), ``status`` (one of :data:`STATUSES`),
    ``measured`` (what was seen, with its numbers and units), ``fix`` (what to do; empty on a pass)
    and ``figures`` (the numbers behind it, JSON-ready, units in the key: ``fps``, ``fill_rate``, ``baseline_m``)."""

    check: str
    status: str
    measured: str
    fix: str = ""
    figures: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status {self.status!r} is not one of {', '.join(STATUSES)}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: NaN and infinities in ``figures`` become null."""
        from check.record import finite

        return {"check": self.check, "status": self.status, "measured": self.measured, "fix": self.fix,
                "figures": finite(dict(self.figures))}


@dataclass(frozen=True)
class DoctorReport:
    """Every finding of one run on ``source`` (a spec), in the order they were checked; ``note``: one line
    that says it all when there is nothing to check (no camera attached: what to plug in), else empty."""

    source: str
    findings: tuple[Finding, ...]
    note: str = ""

    @property
    def status(self) -> str:
        """The worst finding: "fail", else "warn", else "pass"."""
        return worst(f.status for f in self.findings)

    def get(self, check: str) -> Finding:
        """The finding of ``check``; KeyError naming the checks there are."""
        for f in self.findings:
            if f.check == check:
                return f
        raise KeyError(f"no {check!r} finding; there are {', '.join(f.check for f in self.findings)}")

    def to_dict(self) -> dict[str, Any]:
        out = {"source": self.source, "status": self.status, "findings": [f.to_dict() for f in self.findings]}
        return {**out, "message": self.note} if self.note else out


def worst(statuses: Iterable[str]) -> str:
    """The worst of ``statuses``: "fail", else "warn", else "pass" (a skip, or nothing, is no problem)."""
    found = set(statuses)
    return "fail" if "fail" in found else "warn" if "warn" in found else "pass"
