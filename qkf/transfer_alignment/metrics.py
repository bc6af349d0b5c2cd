"""Errors against the truth and the statistics built on them (SI in, display units out).

Error convention as the filter's (SPEC §0): ``δθ = Log(Ĉᵀ C_true)``, ``Δb = b − b̂``,
``Δp = p − p̂``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from qkf.transfer_alignment.states import GROUPS, N_STATES


def state_errors(
    est: np.ndarray, q_true: np.ndarray, bias: np.ndarray, calib: np.ndarray
) -> np.ndarray:
    """True estimation errors (B, n, 15), SI.

    ``est`` (B, n, 16) = [q̂, b̂, p̂]; ``q_true`` (n, 4) or (B, n, 4); ``bias`` (B, n, 3);
    ``calib`` (B, n, 9).
    """
    b, n = est.shape[:2]
    q_hat = est[..., 0:4].reshape(-1, 4)
    q_t = np.broadcast_to(q_true, (b, n, 4)).reshape(-1, 4)
    err = np.empty((b, n, N_STATES))
    finite = np.all(np.isfinite(q_hat), axis=1)
    att = np.full((b * n, 3), np.nan)
    if finite.any():
        att[finite] = (
            Rotation.from_quat(q_hat[finite]).inv() * Rotation.from_quat(q_t[finite])
        ).as_rotvec()
    err[..., 0:3] = att.reshape(b, n, 3)
    err[..., 3:6] = bias - est[..., 4:7]
    err[..., 6:15] = calib - est[..., 7:16]
    return err


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared ``eᵀ P⁻¹ e`` over the last axis; NaN if P is not PD."""
    shape = err.shape[:-1]
    e = err.reshape(-1, err.shape[-1])
    p = cov.reshape(-1, err.shape[-1], err.shape[-1])
    out = np.full(e.shape[0], np.nan)
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(p), axis=(1, 2))
    if ok.any():
        # Scale to unit diagonal first: P spans many orders of magnitude.
        sd = np.sqrt(np.einsum("kii->ki", p[ok]))
        pn = p[ok] / (sd[:, :, None] * sd[:, None, :])
        en = e[ok] / sd
        try:
            chol = np.linalg.cholesky(pn)
        except np.linalg.LinAlgError:
            return _nees_slow(e, p, shape)
        y = np.linalg.solve(chol, en[..., None])[..., 0]
        out[ok] = np.sum(y * y, axis=-1)
    return out.reshape(shape)


def _nees_slow(e: np.ndarray, p: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    out = np.full(e.shape[0], np.nan)
    for i in range(e.shape[0]):
        try:
            c = np.linalg.cholesky(p[i])
        except np.linalg.LinAlgError:
            continue
        y = np.linalg.solve(c, e[i])
        out[i] = float(y @ y)
    return out.reshape(shape)


@dataclass
class ErrorAccumulator:
    """Running sums over trials of squared errors per epoch and state (chunk by chunk)."""

    n_epochs: int
    sum_sq: np.ndarray | None = None
    count: int = 0
    diverged: int = 0

    def add_sums(self, sum_sq: np.ndarray, count: int, diverged: int = 0) -> None:
        """Add a chunk already reduced to its sum of squared errors (n_epochs, 15)."""
        if sum_sq.shape[0] != self.n_epochs:
            raise ValueError(f"expected {self.n_epochs} epochs, got {sum_sq.shape[0]}")
        self.sum_sq = sum_sq.copy() if self.sum_sq is None else self.sum_sq + sum_sq
        self.count += count
        self.diverged += diverged

    def rms(self) -> np.ndarray:
        """RMS over trials (n_epochs, 15); NaN where any trial was non-finite."""
        if self.sum_sq is None or self.count == 0:
            raise ValueError("no trials accumulated")
        return np.sqrt(self.sum_sq / self.count)


def group_rms(ms_per_state: np.ndarray) -> dict[str, np.ndarray]:
    """Root of the mean over each group's states of a mean-square array (..., 15)."""
    return {g: np.sqrt(np.mean(ms_per_state[..., sl], axis=-1)) for g, sl in GROUPS.items()}


def summarize(rms: np.ndarray, final_fraction: float = 0.2) -> dict[str, float]:
    """Group RMS over the last ``final_fraction`` of epochs (``_final``) and over all (``_avg``).

    ``rms`` (n_epochs, 15) is the RMS over trials per epoch; the result is the root of the mean
    square over epochs and over the group's components.
    """
    n = rms.shape[0]
    start = min(n - 1, int(np.floor(n * (1.0 - final_fraction))))
    ms = rms * rms
    out: dict[str, float] = {}
    for g, sl in GROUPS.items():
        out[f"{g}_final"] = float(np.sqrt(np.mean(ms[start:, sl])))
        out[f"{g}_avg"] = float(np.sqrt(np.mean(ms[:, sl])))
    return out
