r"""The filter's moves: everything an adaptive method (or an agent) may change in the
transfer-alignment filter between two decision periods (docs/environment.md, "Controls").

A decision holds for one period; per trial::

    κ          Q_pp = κ · q_p0 · I₉          calibration random walk (scale factor, misalignment)
    q_att      σ_v² ← q_att · σ_v²           attitude process noise (gyro ARW) in Q
    q_bias     σ_u² ← q_bias · σ_u²          bias random walk in Q
    r_scale    σ_a ← r_scale · σ_a           the ADS attitude noise the filter assumes (R ∝ r²)
    reset      P_ii ← P_ii + (f · σ0_i)²      i ∈ calibration, applied once when the period starts

The reset re-inflates the calibration covariance by a fraction ``f`` of each term's prior σ
(added in quadrature to the variance only, as ``glr`` does on an alarm): a change detected is
made learnable again without touching the attitude and bias blocks. The grids below are the
values the environments' discrete actions choose from and the hindsight search tries
(:mod:`qkf.transfer_alignment.methods.hindsight_moves`); κ's grid is the config's action set.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.model import CALIB

BLOCK_SCALES = (0.1, 10.0**-0.5, 1.0, 10.0**0.5, 10.0)
"""Grid of the attitude and bias process-noise factors (``q_att``, ``q_bias``): a decade each
way of the nominal, in half decades."""
R_SCALES = (0.5, 2.0**-0.5, 1.0, 2.0**0.5, 2.0, 2.0**1.5, 4.0)
"""Grid of ``r_scale``, the factor on the assumed ADS attitude σ: ½ to 4 × in steps of √2
(R from ¼ to 16 ×)."""
RESET_FRACTIONS = (0.0, 0.01, 0.03, 0.1, 0.3)
"""Grid of the reset sizes, fractions of the calibration prior σ (0: no reset)."""


@dataclass(frozen=True)
class Moves:
    """One decision per trial (each field (B,)); see the module docstring."""

    kappa: np.ndarray
    q_att: np.ndarray
    q_bias: np.ndarray
    r_scale: np.ndarray
    reset: np.ndarray  # fraction of the prior σ added to each calibration σ now; 0: none

    @classmethod
    def nominal(cls, n: int, kappa: float | np.ndarray = 1.0) -> Moves:
        """No move but ``kappa``: the filter as configured."""
        ones = np.ones(n)
        return cls(np.broadcast_to(kappa, (n,)).astype(float), ones, ones.copy(),
                   ones.copy(), np.zeros(n))  # fmt: skip

    def rows(self, idx: np.ndarray) -> Moves:
        """The decisions of trials ``idx``."""
        return Moves(*(np.asarray(f)[idx] for f in self.fields()))

    def fields(self) -> tuple[np.ndarray, ...]:
        return (self.kappa, self.q_att, self.q_bias, self.r_scale, self.reset)

    def put(self, rows: np.ndarray, other: Moves) -> None:
        """Overwrite trials ``rows`` with ``other``'s decisions for the same trials, in place."""
        for mine, theirs in zip(self.fields(), other.fields(), strict=True):
            mine[rows] = theirs[rows]

    def check(self) -> None:
        """``ValueError`` unless every factor is finite and positive and every reset finite and
        non-negative."""
        for name, v in zip(("kappa", "q_att", "q_bias", "r_scale"), self.fields()[:4], strict=True):
            if not np.all(np.isfinite(v) & (v > 0.0)):
                raise ValueError(f"{name} must be finite and positive")
        if not np.all(np.isfinite(self.reset) & (self.reset >= 0.0)):
            raise ValueError("reset must be finite and non-negative")


def reopen_calibration(
    kf: TransferAlignmentKF, rows: np.ndarray, sigma: float | np.ndarray
) -> None:
    """Add ``σ²`` (SI: rad² for a misalignment, 1 for a scale factor; a scalar or one per
    calibration term (9,)) to the nine calibration variances of the trials where ``rows``
    (B,) is true; every other entry, and every other trial's covariance, is left bit for bit
    as it was."""
    if not np.any(rows):
        return
    # kf.P's setter rescales every trial (a round trip that changes the last bit of about one
    # entry in seven), so the new covariance is built in a copy and loaded into the chosen
    # trials only
    opened = kf.copy()
    p = opened.P
    idx = np.arange(CALIB.start, CALIB.stop)
    p[:, idx, idx] += np.asarray(sigma, dtype=float) ** 2  # P_ii ← P_ii + σ_r²
    opened.P = p
    for i in np.flatnonzero(rows).tolist():
        kf.load_trial(i, opened, i)


def apply_moves(kf: TransferAlignmentKF, moves: Moves) -> np.ndarray:
    """Set the filter's process-noise factors and assumed ADS σ for the next period, apply
    the resets now; returns the κ (B,) to step with. Nominal moves leave the filter bit for
    bit as configured."""
    moves.check()
    kf.q_scale[:, 0] = moves.q_att
    kf.q_scale[:, 1] = moves.q_bias
    kf.sigma_a[:] = kf.params.sigma_a * moves.r_scale  # σ_a ← r · σ_a (R ∝ r²)
    prior = kf.params.p0_sigma[CALIB]
    for f in np.unique(moves.reset[moves.reset > 0.0]).tolist():
        reopen_calibration(kf, moves.reset == f, f * prior)  # P_ii += (f σ0_i)²
    return np.asarray(moves.kappa, dtype=float)


def grid_position(values: np.ndarray, grid: tuple[float, ...] | np.ndarray) -> np.ndarray:
    """Where ``values`` lie on a grid's log range, 0 … 1 (a grid's first value 0, its last 1;
    clipped). For display in observations."""
    lo, hi = np.log(grid[0]), np.log(grid[-1])
    with np.errstate(divide="ignore"):
        return np.clip((np.log(values) - lo) / (hi - lo), 0.0, 1.0)
