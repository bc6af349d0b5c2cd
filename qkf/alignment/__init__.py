"""Attitude-independent alignment calibration of vector sensors (docs/alignment.md)."""
