"""`depthruler doctor`: the first thing to run when a camera is plugged in (checks as plain functions, findings as data)."""

from check.doctor.findings import DoctorReport, Finding
from check.doctor.run import NO_CAMERA, attached_source, run_doctor

__all__ = ["NO_CAMERA", "DoctorReport", "Finding", "attached_source", "run_doctor"]
