r"""MMAE: a bank of parallel filters, one per κ of the action set (docs/methods.md).

Model probabilities follow the innovation likelihood of each filter::

    log w_i,k = log w_i,k−1 + ℓ_i,k − log Σ_j exp(…),   ℓ = −½ (νᵀ S⁻¹ ν + log det S)

with a floor on each weight (renormalised) so that no model is locked out for good. The output
is the weighted estimate: ``b̂``, ``p̂`` as weighted means, the attitude as the weighted mean
rotation vector about the most probable filter's attitude. The filters do not interact.

:func:`run_mmae` runs the whole bank (A × B filters) in one compiled call
(:func:`~qkf.transfer_alignment.methods.bank_compiled.run_bank`): the filter epoch, the weight
recursion and the combination per trial and epoch, trials in parallel. The numpy functions here
(:func:`update_log_weights`, :func:`combine`, and :func:`run_mmae_reference`, the same method
driven from numpy in blocks of epochs) are its documented references; the tests check the
compiled bank against them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from qkf.core.quat import attitude_error
from qkf.core.so3 import quat_exp, quat_mul
from qkf.transfer_alignment.adaptive import MmaeConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import FilterRecord, TransferAlignmentKF
from qkf.transfer_alignment.methods.bank_compiled import BankRun, run_bank
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    action_values,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import (
    CovarianceRecorder,
    mixture_covariance,
    step_arrays,
)
from qkf.transfer_alignment.scenario import ScenarioData

BLOCK = 200


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


@uses_settings("mmae", MmaeConfig)
def run_mmae(cfg: Config, data: ScenarioData) -> MethodOutput:
    """The bank over all trials, compiled (module doc); logs the model probabilities per epoch
    (``weights``)."""
    kappas = action_values(cfg)
    bank, run, cov = run_compiled_bank(cfg, data, kappas, floor=cfg.adaptive.mmae.weight_floor)
    return _output(bank, kappas, run.est, run.weights, cov)


def run_compiled_bank(
    cfg: Config, data: ScenarioData, kappas: np.ndarray, **options: Any
) -> tuple[TransferAlignmentKF, BankRun, np.ndarray]:
    """A bank of one filter per κ of ``kappas`` (A,) and trial (rows ``trial · A + model``) over
    all epochs of ``data`` in one compiled call: :func:`~.bank_compiled.run_bank` with
    ``options`` (``floor`` for MMAE; ``trans``, ``mix_every`` for IMM). Returns the bank at the
    end of the run, the run, and the mixture covariance at the sampled epochs (B, M, 15, 15)."""
    bank = new_filter(cfg, data, n_copies=kappas.size)
    cov = CovarianceRecorder(cfg, data.n_trials)
    run = run_bank(bank, data, kappas, cov.epochs, cov.cov, **options)
    return bank, run, cov.cov


def _output(
    bank: TransferAlignmentKF,
    kappas: np.ndarray,
    est: np.ndarray,
    weights: np.ndarray,
    cov: np.ndarray,
) -> MethodOutput:
    """The method's output from the bank's combined estimates and weights (B, N, A)."""
    b, _, n_act = weights.shape
    diverged = np.asarray(bank.diverged.reshape(b, n_act).all(axis=1))
    # κ in use: the probability-weighted geometric mean of the bank's κ
    kappa = np.exp(weights @ np.log(kappas))
    return MethodOutput(est=est, diverged=diverged, kappa=kappa, logs={"weights": weights}, cov=cov)


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
