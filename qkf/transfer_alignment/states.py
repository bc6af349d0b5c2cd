"""The 15-value error state: names, groups and display units (docs/models.md).

State order: ``x = [δθ (3), Δb (3), Δp (9)]`` with
``p = [s_x, s_y, s_z, k_xy, k_xz, k_yz, k_yx, k_zx, k_zy]``.
"""

from __future__ import annotations

import numpy as np

from qkf.core.units import ARCSEC, DEG_PER_H, PPM, URAD

N_STATES = 15

STATE_COLUMNS: tuple[str, ...] = (
    "att_x_arcsec",
    "att_y_arcsec",
    "att_z_arcsec",
    "bias_x_degph",
    "bias_y_degph",
    "bias_z_degph",
    "sf_x_ppm",
    "sf_y_ppm",
    "sf_z_ppm",
    "ma_xy_urad",
    "ma_xz_urad",
    "ma_yz_urad",
    "ma_yx_urad",
    "ma_zx_urad",
    "ma_zy_urad",
)
"""CSV column names of the 15 states, in state order, with their display unit."""

GROUPS: dict[str, slice] = {
    "att_arcsec": slice(0, 3),
    "bias_degph": slice(3, 6),
    "sf_ppm": slice(6, 9),
    "ma_urad": slice(9, 15),
}
"""State groups used in summaries and plots, keyed by their summary-column stem."""

GROUP_TITLES: dict[str, str] = {
    "att_arcsec": "attitude [arcsec]",
    "bias_degph": "gyro bias [deg/h]",
    "sf_ppm": "scale factor [ppm]",
    "ma_urad": "misalignment [µrad]",
}

DISPLAY_UNIT: np.ndarray = np.array([ARCSEC] * 3 + [DEG_PER_H] * 3 + [PPM] * 3 + [URAD] * 6)
"""SI value of one display unit, per state: ``display = si / DISPLAY_UNIT``."""


def to_display(x_si: np.ndarray) -> np.ndarray:
    """Convert SI state values (last axis of length 15) to display units."""
    x_si = np.asarray(x_si, dtype=float)
    if x_si.shape[-1] != N_STATES:
        raise ValueError(f"expected a last axis of {N_STATES} states, got shape {x_si.shape}")
    return x_si / DISPLAY_UNIT
