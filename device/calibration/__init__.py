"""Stereo calibration: the ChArUco board, calibrating a pair, and the calibration file formats."""
