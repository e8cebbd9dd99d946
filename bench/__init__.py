"""Benchmarks (`depthruler bench NAME`): each ``bench_*.py`` module has a ``main(argv)`` and records
its figures in ``bench/RESULTS.md`` with ``--write``, as ratios against a reference in the same run."""
