"""Transfer alignment: in-orbit gyro calibration against a master's attitude reference."""
