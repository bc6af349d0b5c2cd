"""Errors of transfer-alignment estimates against the truth, and their summaries (SI in,
display units out). Generic statistics (NEES, running sums) are in :mod:`qkf.core.stats`.

Error convention as the filter's (docs/models.md): ``δθ = Log(Ĉᵀ C_true)``, ``Δb = b − b̂``,
``Δp = p − p̂``.
"""

from __future__ import annotations

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
