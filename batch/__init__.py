"""Batch re-measurement (`depthruler batch`): task tables in, one result row per task out, on this
machine, a process pool or a Ray cluster."""
