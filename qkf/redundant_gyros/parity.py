r"""Parity-space generalised likelihood test, GLT (docs/redundant_gyros.md, "GLT").

With the compensated readings whitened, ``ỹ_i = y_i / s_i`` (``s_i`` the noise sd after
compensation), and ``V`` the parity matrix of the whitened geometry (``V G̃ = 0``, ``V Vᵀ = I``),
the parity vector ``p = V ỹ`` does not depend on the body rate; without a fault
``p ~ N(0, I_{n−3})``. Per epoch:

    detection:  pᵀp > χ²⁻¹(1 − P_FA, n − 3)
    isolation:  argmax_i (pᵀ v_i)² / ‖v_i‖²          (v_i the columns of V)

Windowed variant over the last N epochs (fewer at the start): the statistic is
``Σ_k p_kᵀ p_k`` against ``χ²⁻¹(1 − P_FA, N (n − 3))`` and the isolation sums the per-epoch
scores, ``argmax_i Σ_k (p_kᵀ v_i)² / ‖v_i‖²`` — the likelihood ratio for one faulty gyro whose
error may change from epoch to epoch (a misalignment or scale fault follows the body rate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from qkf.redundant_gyros.geometry import GyroUnit
from qkf.redundant_gyros.threecross import NO_GYRO, window_sums


def parity(unit: GyroUnit, y: np.ndarray) -> np.ndarray:
    """Parity vectors ``V (y / s)`` of compensated readings ``y`` (..., n): (..., n − 3)."""
    return np.asarray((y / unit.comp_noise) @ unit.v_parity.T)


@dataclass(frozen=True)
class GltResult:
    statistic: np.ndarray  # (B, E) pᵀp, summed over the window
    threshold: np.ndarray  # (E,) χ² threshold for the window length at each epoch
    isolated: np.ndarray  # (B, E) gyro index, NO_GYRO where not detected

    @property
    def detected(self) -> np.ndarray:
        return np.asarray(self.isolated != NO_GYRO)


@dataclass(frozen=True)
class GltDetector:
    unit: GyroUnit
    window: int
    false_alarm: float

    @property
    def dof(self) -> int:
        return self.unit.n - 3

    def thresholds(self, n_epochs: int) -> np.ndarray:
        length = np.minimum(np.arange(n_epochs) + 1, self.window)
        table = stats.chi2.ppf(1.0 - self.false_alarm, np.arange(1, self.window + 1) * self.dof)
        return np.asarray(table[length - 1])

    def test(self, y: np.ndarray) -> GltResult:
        """Detection and isolation for readings ``y`` (B, E, n)."""
        p = parity(self.unit, y)  # (B, E, n − 3)
        v = self.unit.v_parity
        norms = np.linalg.norm(v, axis=0)
        scale = max(float(norms.max(initial=0.0)), 1e-300)
        usable = norms > 1e-9 * scale
        vn = np.where(usable, v / np.where(usable, norms, 1.0), 0.0)
        stat = np.sum(p * p, axis=-1)
        score = (p @ vn) ** 2  # (B, E, n)
        if self.window > 1:
            stat = window_sums(stat, self.window)
            score = window_sums(score, self.window)
        score = np.where(usable, score, -np.inf)
        thr = self.thresholds(y.shape[1])
        iso = np.argmax(score, axis=-1)
        isolated = np.where(stat > thr, iso, NO_GYRO).astype(np.int16)
        return GltResult(statistic=stat, threshold=thr, isolated=isolated)
