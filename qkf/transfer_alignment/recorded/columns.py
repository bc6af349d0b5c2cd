"""The columns of a recorded transfer-alignment run (docs/recorded_data.md, "Input").

One row per epoch; SI units; ``C`` body → inertial, quaternions scalar-last; the calibration
vector in the order ``p = [s_x, s_y, s_z, k_xy, k_xz, k_yz, k_yx, k_zx, k_zy]``.
"""

from __future__ import annotations

TIME = "t_s"
ADS_Q: tuple[str, ...] = ("ads_qx", "ads_qy", "ads_qz", "ads_qw")
"""The master ADS attitude; all four empty: none at this epoch."""
ADS_RATE: tuple[str, ...] = ("ads_wx_rad_s", "ads_wy_rad_s", "ads_wz_rad_s")
"""The master's body rate, rad/s; all three empty: none at this epoch."""
GYRO: tuple[str, ...] = ("gyro_wx_rad_s", "gyro_wy_rad_s", "gyro_wz_rad_s")
"""The slave gyro output, rad/s (never empty)."""
REQUIRED_COLUMNS: tuple[str, ...] = (TIME, *ADS_Q, *ADS_RATE, *GYRO)

TRUE_Q: tuple[str, ...] = ("true_qx", "true_qy", "true_qz", "true_qw")
TRUE_BIAS: tuple[str, ...] = ("true_bias_x_rad_s", "true_bias_y_rad_s", "true_bias_z_rad_s")
TRUE_P: tuple[str, ...] = tuple(
    f"true_p_{name}"
    for name in ("s_x", "s_y", "s_z", "k_xy", "k_xz", "k_yz", "k_yx", "k_zx", "k_zy")
)
"""The true calibration, dimensionless, in calibration order."""
TRUTH_COLUMNS: tuple[str, ...] = (*TRUE_Q, *TRUE_BIAS, *TRUE_P)
"""Optional: all sixteen or none."""
ALL_COLUMNS: tuple[str, ...] = (*REQUIRED_COLUMNS, *TRUTH_COLUMNS)

OPTIONAL_GROUPS: dict[str, tuple[str, ...]] = {"ADS attitude": ADS_Q, "ADS rate": ADS_RATE}
"""Column groups that may be empty together (absent at that epoch), never in part."""
RATE_COLUMNS: tuple[tuple[str, ...], ...] = (ADS_RATE, GYRO)
"""Rates checked for plausibility in rad/s."""
QUATERNIONS: tuple[tuple[str, ...], ...] = (ADS_Q, TRUE_Q)
"""Quaternions checked for unit norm (and renormalised within the tolerance)."""
EXTENSIONS: dict[str, str] = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}
