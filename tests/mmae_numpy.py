"""The numpy reference of the MMAE bank (qkf/transfer_alignment/methods/mmae.py), for the tests.

The method runs compiled (:func:`qkf.transfer_alignment.methods.bank_compiled.run_bank`); these
are the same equations in numpy: the weight recursion, the combination of the bank's estimates,
the mixture covariance about it, and :func:`run_mmae_reference`, which drives the filter bank
with them block by block. The tests hold the compiled bank to them (to rounding).
"""

from __future__ import annotations

import numpy as np

from qkf.core.quat import attitude_error
from qkf.core.so3 import quat_exp, quat_mul
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import FilterRecord, TransferAlignmentKF
from qkf.transfer_alignment.methods.base import MethodOutput, action_values, new_filter
from qkf.transfer_alignment.methods.covariance import N_STATES, CovarianceRecorder, step_arrays
from qkf.transfer_alignment.methods.mmae import _output
from qkf.transfer_alignment.scenario import ScenarioData

BLOCK = 200  # epochs per combination of the bank's estimates (bounds memory)


def update_log_weights(log_w: np.ndarray, loglik: np.ndarray, floor: float) -> np.ndarray:
    """One step of the Bayesian model-probability recursion over the last axis, with a floor.

    A model with a non-finite likelihood (diverged) gets weight zero for good.
    """
    alive = np.isfinite(loglik) & np.isfinite(log_w)
    lw = np.where(alive, log_w + np.where(alive, loglik, 0.0), -np.inf)
    lw = lw - lw.max(axis=-1, keepdims=True)
    w = np.exp(lw)
    w /= w.sum(axis=-1, keepdims=True)
    if floor > 0.0:
        w = np.where(alive, np.maximum(w, floor), 0.0)
        w /= w.sum(axis=-1, keepdims=True)
    with np.errstate(divide="ignore"):
        return np.log(w)


def combine(est: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted estimate from a bank: ``est`` (B, A, n, 16), ``w`` (B, A, n) → (B, n, 16)::

        b̂ = Σ_j w_j b̂_j,   p̂ = Σ_j w_j p̂_j
        δθ_j = Log(Ĉ_refᵀ Ĉ_j),   Ĉ = Ĉ_ref Exp(Σ_j w_j δθ_j)   (normalised)

    with ``Ĉ_ref`` the estimate of the most probable model (the first, on a tie); rad.
    """
    out = np.empty((est.shape[0], est.shape[2], 16))
    out[..., 4:] = np.einsum("ban,banj->bnj", w, est[..., 4:])
    best = w.argmax(axis=1)  # (B, n)
    q_ref = np.take_along_axis(est[..., 0:4], best[:, None, :, None], axis=1)  # (B, 1, n, 4)
    rel = attitude_error(q_ref, est[..., 0:4])  # δθ_j = Log(Ĉ_refᵀ Ĉ_j)
    mean_rel = np.einsum("ban,banj->bnj", w, rel)  # Σ_j w_j δθ_j
    q = quat_mul(q_ref[:, 0], quat_exp(mean_rel))  # Ĉ_ref Exp(Σ_j w_j δθ_j)
    out[..., 0:4] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return out


def step_bank(
    bank: TransferAlignmentKF,
    data: ScenarioData,
    k0: int,
    k1: int,
    kappa_rows: np.ndarray,
    recorder: CovarianceRecorder,
) -> FilterRecord:
    """Run a bank of A filters per trial (rows trial × A + member, κ per row) over epochs
    ``[k0, k1)``: every member sees its trial's data; covariances go to ``recorder``."""
    n_act = bank.n_trials // data.n_trials
    sl = slice(k0, k1)
    return step_arrays(
        bank,
        np.repeat(data.gyro[:, sl], n_act, axis=0),
        np.repeat(data.ads_q[:, sl], n_act, axis=0),
        np.repeat(data.ads_rate[:, sl], n_act, axis=0),
        data.has_meas[..., sl],
        kappa_rows,
        k0,
        recorder,
    )


def neutral_dead(bank_est: np.ndarray) -> np.ndarray:
    """A copy of bank estimates (..., 16) with diverged members' rows set to neutral values
    (they carry weight 0; neutral values keep the weighted sums finite)."""
    e = bank_est.copy()
    dead = ~np.isfinite(e).all(axis=-1)
    e[dead] = 0.0
    e[dead, 3] = 1.0
    return e


def record_bank_covariance(
    out: CovarianceRecorder,
    bank: CovarianceRecorder,
    k0: int,
    bank_est: np.ndarray,
    w: np.ndarray,
    est_mix: np.ndarray,
) -> None:
    """The bank's mixture covariance (:func:`mixture_covariance`) at the sampled epochs of a block
    starting at epoch ``k0``: ``bank_est`` (B, A, n, 16), ``w`` (B, A, n), ``est_mix`` (B, n, 16);
    ``bank`` holds the members' covariances (rows trial × A + member)."""
    b, n_act, n = w.shape
    for k in out.sampled_in(k0, k0 + n):
        j = int(np.searchsorted(bank.epochs, k))
        members = bank.cov[:, j].reshape(b, n_act, 15, 15)
        i = k - k0
        out.take(k, mixture_covariance(bank_est[:, :, i], members, w[:, :, i], est_mix[:, i]))


def run_mmae_reference(cfg: Config, data: ScenarioData) -> MethodOutput:
    """:func:`run_mmae` driven from numpy: the bank in blocks of ``BLOCK`` epochs through the
    filter's :meth:`~TransferAlignmentKF.step`, then :func:`update_log_weights` epoch by epoch and
    :func:`combine` per block. The reference the compiled bank is tested against (equal to
    rounding); about twice as slow."""
    kappas = action_values(cfg)
    n_act = kappas.size
    b, n = data.n_trials, data.n_epochs
    bank = new_filter(cfg, data, n_copies=n_act)  # row = trial * A + model
    kappa_rows = np.tile(kappas, b)
    floor = cfg.adaptive.mmae.weight_floor
    log_w = np.full((b, n_act), -np.log(n_act))
    est = np.empty((b, n, 16))
    weights = np.empty((b, n, n_act))
    cov = CovarianceRecorder(cfg, b)
    bank_cov = CovarianceRecorder(cfg, b * n_act)
    for k0 in range(0, n, BLOCK):
        k1 = min(n, k0 + BLOCK)
        sl = slice(k0, k1)
        rec = step_bank(bank, data, k0, k1, kappa_rows, bank_cov)
        ll = rec.loglik.reshape(b, n_act, k1 - k0)
        w_block = np.empty((b, n_act, k1 - k0))
        for k in range(k1 - k0):
            log_w = update_log_weights(log_w, ll[:, :, k], floor)
            w_block[:, :, k] = np.exp(log_w)
        weights[:, sl] = np.moveaxis(w_block, 1, 2)
        bank_est = neutral_dead(rec.est.reshape(b, n_act, k1 - k0, 16))
        est[:, sl] = combine(bank_est, w_block)
        record_bank_covariance(cov, bank_cov, k0, bank_est, w_block, est[:, sl])
    return _output(bank, kappas, est, weights, cov.cov)


def mixture_covariance(
    est: np.ndarray, cov: np.ndarray, weights: np.ndarray, est_mix: np.ndarray
) -> np.ndarray:
    """Covariance of a weighted bank about its combined estimate (B, 15, 15).

    ``P = Σ_a w_a (P_a + d_a d_aᵀ)`` with ``d_a`` the bank member's estimate relative to the
    combined one in the error-state convention (``δθ = Log(Ĉ_mixᵀ Ĉ_a)``, ``Δb = b̂_a − b̂_mix``,
    ``Δp = p̂_a − p̂_mix``). ``est`` (B, A, 16), ``cov`` (B, A, 15, 15), ``weights`` (B, A)
    summing to one, ``est_mix`` (B, 16). Members with weight 0 (diverged) are left out.
    """
    b, n_act = weights.shape
    use = (weights > 0.0) & np.isfinite(est).all(axis=-1) & np.isfinite(cov).all(axis=(-1, -2))
    w = np.where(use, weights, 0.0)
    d = np.zeros((b, n_act, N_STATES))
    ok_mix = np.isfinite(est_mix).all(axis=-1)
    rows = use & ok_mix[:, None]
    if rows.any():
        q_mix = np.broadcast_to(est_mix[:, None, 0:4], (b, n_act, 4))[rows]
        d[rows, 0:3] = attitude_error(q_mix, est[rows][:, 0:4])  # δθ = Log(Ĉ_mixᵀ Ĉ_a)
        d[rows, 3:] = est[rows][:, 4:] - np.broadcast_to(est_mix[:, None, 4:], (b, n_act, 12))[rows]
    spread = cov + d[..., :, None] * d[..., None, :]
    out = np.einsum("ba,baij->bij", w, np.where(use[..., None, None], spread, 0.0))
    out[~ok_mix | ~use.any(axis=1)] = np.nan
    return 0.5 * (out + np.swapaxes(out, -1, -2))
