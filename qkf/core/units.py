"""Unit conversions. Everything inside qkf is SI (rad, rad/s, s); these factors are for the edges.

Multiply a value in the named unit by the factor to get SI; divide an SI value to display it.
"""

from __future__ import annotations

import math

DEG = math.pi / 180.0
"""1 degree in rad."""
ARCSEC = DEG / 3600.0
"""1 arcsecond in rad."""
DEG_PER_S = DEG
"""1 deg/s in rad/s."""
DEG_PER_H = DEG / 3600.0
"""1 deg/h in rad/s."""
DEG_PER_SQRT_H = DEG / 60.0
"""1 deg/sqrt(h) (angle random walk) in rad/sqrt(s)."""
DEG_PER_H_1_5 = DEG / 3600.0**1.5
"""1 deg/h^1.5 (rate random walk) in rad/s^1.5."""
PPM = 1e-6
"""1 part per million, dimensionless."""
URAD = 1e-6
"""1 microradian in rad."""

MU_EARTH = 3.986004418e14
"""Earth's gravitational parameter, m^3/s^2."""
R_EARTH = 6378137.0
"""Earth's equatorial radius, m."""
