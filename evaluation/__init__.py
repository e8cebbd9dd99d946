"""Evaluation and batch re-measurement: the paper's study on the simulator, real stereo
(Middlebury) protocols, reports with plots, `depthruler batch` over recording archives or the
service's history, and the executors they share (this process, a process pool, Ray). Imports
``measure``, ``device`` and ``sim``; nothing here imports ``service``."""
