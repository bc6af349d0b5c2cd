"""The columns of a recorded transfer-alignment run (docs/recorded_data.md, "Input").

One row per epoch; SI units; ``C`` body → inertial, quaternions scalar-last; the calibration
vector in the order ``p = [s_x, s_y, s_z, k_xy, k_xz, k_yz, k_yx, k_zx, k_zy]``.
"""

from __future__ import annotations

TIME = "t_s"
"""Time, s; strictly increasing (the step may vary)."""
ADS_Q: tuple[str, ...] = ("ads_qx", "ads_qy", "ads_qz", "ads_qw")
"""The master ADS attitude; all four empty: none at this epoch."""
ADS_RATE: tuple[str, ...] = ("ads_wx_rad_s", "ads_wy_rad_s", "ads_wz_rad_s")
"""The master's body rate, rad/s; all three empty: none at this epoch."""
GYRO: tuple[str, ...] = ("gyro_wx_rad_s", "gyro_wy_rad_s", "gyro_wz_rad_s")
"""The slave gyro output, rad/s (never empty)."""
REQUIRED_COLUMNS: tuple[str, ...] = (TIME, *ADS_Q, *ADS_RATE, *GYRO)

CALIBRATION_NAMES: tuple[str, ...] = (
    "s_x",
    "s_y",
    "s_z",
    "k_xy",
    "k_xz",
    "k_yz",
    "k_yx",
    "k_zx",
    "k_zy",
)
"""The calibration vector's elements, in calibration order."""
TRUE_Q: tuple[str, ...] = ("true_qx", "true_qy", "true_qz", "true_qw")
"""The true attitude (never empty when present)."""
TRUE_BIAS: tuple[str, ...] = ("true_bias_x_rad_s", "true_bias_y_rad_s", "true_bias_z_rad_s")
"""The true gyro bias, rad/s."""
TRUE_P: tuple[str, ...] = tuple(f"true_p_{name}" for name in CALIBRATION_NAMES)
"""The true calibration, dimensionless, in calibration order."""
TRUTH_COLUMNS: tuple[str, ...] = (*TRUE_Q, *TRUE_BIAS, *TRUE_P)
"""Optional: all sixteen or none."""
ALL_COLUMNS: tuple[str, ...] = (*REQUIRED_COLUMNS, *TRUTH_COLUMNS)
"""Every allowed column, in the order the writer writes them."""

GROUPS: dict[str, tuple[str, ...]] = {
    "t": (TIME,),
    "ads_q": ADS_Q,
    "ads_rate": ADS_RATE,
    "gyro": GYRO,
    "true_q": TRUE_Q,
    "true_bias": TRUE_BIAS,
    "true_p": TRUE_P,
}
"""The arrays a file is read into (``RecordedRun`` / ``RecordedTruth`` fields), and their
columns in array order."""
OPTIONAL_GROUPS: dict[str, tuple[str, ...]] = {"ADS attitude": ADS_Q, "ADS rate": ADS_RATE}
"""Column groups that may be empty together (absent at that epoch), never in part."""
NEVER_EMPTY: tuple[str, ...] = (TIME, *GYRO, *TRUTH_COLUMNS)
"""Columns whose every cell must hold a number."""
RATE_COLUMNS: tuple[tuple[str, ...], ...] = (ADS_RATE, GYRO)
"""Rates checked for plausibility in rad/s."""
QUATERNIONS: tuple[tuple[str, ...], ...] = (ADS_Q, TRUE_Q)
"""Quaternions checked for unit norm (and renormalised within the tolerance)."""
EXTENSIONS: dict[str, str] = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}
"""File name endings (case-insensitive) and the format they stand for."""
