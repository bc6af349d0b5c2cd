"""Redundant skewed gyros: fault detection and isolation (three-cross, parity GLT) and UKF
calibration of the isolated gyro (docs/redundant_gyros.md)."""
