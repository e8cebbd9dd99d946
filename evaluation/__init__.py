"""Evaluation and batch re-measurement: the paper's study on the simulator, real stereo
(Middlebury) protocols, reports with plots, and the executors they share. Imports ``measure``,
``device`` and ``sim``; nothing here imports ``service``."""
