"""The numpy reference of the IMM (qkf/transfer_alignment/methods/imm.py), for the tests.

The method runs compiled (:func:`qkf.transfer_alignment.methods.bank_compiled.run_bank`); these
are the same equations written from the textbook in numpy, batched over leading axes, and
:func:`imm_filter_reference` drives the filter bank with them epoch by epoch. The tests hold
the compiled bank to them (to rounding; docs/methods.md, "IMM"), so they live here, beside the
tests that read them, not in the package that never runs them.
"""

from __future__ import annotations

import math

import numpy as np

from qkf.core.quat import attitude_error
from qkf.core.so3 import quat_exp, quat_mul, skew
from qkf.transfer_alignment.adaptive import ImmConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.methods.base import MethodOutput, action_values, new_filter
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder
from qkf.transfer_alignment.methods.imm import _output, transition_matrix
from qkf.transfer_alignment.model import CALIB, N_STATES, THETA, omega_matrix, rate_matrix
from qkf.transfer_alignment.scenario import ScenarioData
from tests.mmae_numpy import combine, neutral_dead, record_bank_covariance, step_bank

BLOCK = 200  # epochs per combination of the bank's estimates (bounds memory)


UNIT_Q_ORDER = 4
"""Highest total power of ``[ω̂×] Δt`` in the series of :func:`unit_calibration_noise`."""


def mixing_probabilities(mu: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``c̄`` (…, A) and the mixing probabilities ``μ_i|j`` (…, A_i, A_j) from ``μ`` (…, A).

    ``c̄_j = Σ_i Π_ij μ_i``, ``μ_i|j = Π_ij μ_i / c̄_j``. A model with ``c̄_j = 0`` (possible only
    with zeros in ``Π``) keeps its own state: ``μ_i|j = δ_ij``.
    """
    joint = trans * mu[..., :, None]  # Π_ij μ_i
    c_bar = joint.sum(axis=-2)  # c̄_j = Σ_i Π_ij μ_i
    safe = np.where(c_bar > 0.0, c_bar, 1.0)
    mix = np.where(c_bar[..., None, :] > 0.0, joint / safe[..., None, :], np.eye(trans.shape[-1]))
    return c_bar, mix


def mix_moments(x: np.ndarray, cov: np.ndarray, mix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mixed means (…, A, n) and covariances (…, A, n, n) of A Gaussians ``x`` (…, A, n),
    ``cov`` (…, A, n, n) with mixing probabilities ``mix`` (…, A_i, A_j).

    ``x̂0_j = Σ_i μ_i|j x̂_i``, ``P0_j = Σ_i μ_i|j (P_i + d_ij d_ijᵀ)``, ``d_ij = x̂_i − x̂0_j``.
    Evaluated as ``Σ_i μ_i|j (P_i + y_i y_iᵀ) − y0_j y0_jᵀ`` (the same, since ``Σ_i μ_i|j = 1``)
    with ``y = x − x̄`` centred on the models' plain mean, which keeps the cancellation at the
    size of the spread; A outer products instead of A².
    """
    n = x.shape[-1]
    mt = np.swapaxes(mix, -1, -2)  # (…, A_j, A_i)
    centre = x.mean(axis=-2, keepdims=True)
    y = x - centre
    y0 = mt @ y  # y0_j = Σ_i μ_i|j y_i
    second = cov + y[..., :, None] * y[..., None, :]  # P_i + y_i y_iᵀ
    p0 = (mt @ second.reshape(*second.shape[:-2], n * n)).reshape(*y0.shape, n)
    p0 -= y0[..., :, None] * y0[..., None, :]  # − y0_j y0_jᵀ
    return y0 + centre, p0


def update_model_probabilities(c_bar: np.ndarray, loglik: np.ndarray) -> np.ndarray:
    """``μ_j ∝ Λ_j c̄_j``, ``Λ_j = exp(ℓ_j)``, over the last axis, in the log domain.

    A model with a non-finite ``ℓ`` (diverged) gets ``μ = 0``; a row with no live model, all
    zeros.
    """
    alive = np.isfinite(loglik) & (c_bar > 0.0)
    with np.errstate(divide="ignore"):
        lw = np.where(
            alive, np.log(np.where(alive, c_bar, 1.0)) + np.where(alive, loglik, 0.0), -np.inf
        )
    top = lw.max(axis=-1, keepdims=True)
    w = np.exp(lw - np.where(np.isfinite(top), top, 0.0))
    tot = w.sum(axis=-1, keepdims=True)
    return np.where(tot > 0.0, w / np.where(tot > 0.0, tot, 1.0), 0.0)


def unit_calibration_noise(dt: float, rate: np.ndarray, p_hat: np.ndarray) -> np.ndarray:
    """``U = ∂Q_d/∂q_p`` (…, 15, 15) in s: the part of ``Q_d`` per unit calibration density, at
    the rate ``rate`` (…, 3, rad/s) the propagation used and ``A = (I + K(p̂))⁻¹``.

    With ``W = [ω̂×]``, ``Γ(s) = Σ_n (−W)ⁿ sⁿ⁺¹/(n+1)!`` and ``M = A Ω Ωᵀ Aᵀ``::

        U_θθ = ∫₀^Δt Γ M Γᵀ ds = Σ_{n,m} (−W)ⁿ M Wᵐ Δtⁿ⁺ᵐ⁺³ / ((n+1)! (m+1)! (n+m+3))
        U_θp = −(∫₀^Δt Γ ds) A Ω = −Σ_n (−W)ⁿ Δtⁿ⁺² / (n+2)! · A Ω,      U_pp = Δt I

    summed to ``n + m ≤ UNIT_Q_ORDER`` (relative error ~ (|ω̂|Δt)⁵/5!: 1e-11 at 1 deg/s and
    Δt = 1 s; checked against :func:`model.discretize` in the tests).
    """
    a = rate_matrix(p_hat)  # A = (I + K(p̂))⁻¹
    aom = a @ omega_matrix(rate)  # A Ω(ω̂)   (…, 3, 9)
    m = aom @ np.swapaxes(aom, -1, -2)  # A Ω Ωᵀ Aᵀ
    neg_w = -skew(rate)
    powers = [np.broadcast_to(np.eye(3), neg_w.shape)]  # (−W)ⁿ
    for _ in range(UNIT_Q_ORDER):
        powers.append(powers[-1] @ neg_w)
    fact = [float(math.factorial(i)) for i in range(UNIT_Q_ORDER + 3)]
    g = sum(powers[n] * (dt ** (n + 2) / fact[n + 2]) for n in range(UNIT_Q_ORDER + 1))
    u_tt = np.zeros(neg_w.shape)
    for n in range(UNIT_Q_ORDER + 1):
        left = powers[n] @ m
        for k in range(UNIT_Q_ORDER + 1 - n):
            c = dt ** (n + k + 3) / (fact[n + 1] * fact[k + 1] * (n + k + 3))
            u_tt += c * (left @ np.swapaxes(powers[k], -1, -2))  # (−W)ᵏᵀ = Wᵏ
    u = np.zeros((*rate.shape[:-1], N_STATES, N_STATES))
    u[..., THETA, THETA] = 0.5 * (u_tt + np.swapaxes(u_tt, -1, -2))
    u_tp = -np.asarray(g) @ aom
    u[..., THETA, CALIB] = u_tp
    u[..., CALIB, THETA] = np.swapaxes(u_tp, -1, -2)
    u[..., CALIB, CALIB] = dt * np.eye(9)
    return u


def mix_bank(
    kf: TransferAlignmentKF,
    mu: np.ndarray,
    trans: np.ndarray,
    kappas: np.ndarray,
    unit_q: np.ndarray,
    live: np.ndarray,
) -> np.ndarray:
    """Mix the bank (rows ``trial * A + model``) in place on its predicted states; returns ``c̄``.

    ``mu`` (B, A) model probabilities; ``unit_q`` (B, 15, 15) the ``U`` of the last propagation,
    per trial (its models' ``ω̂`` and ``A`` differ by parts in 10⁶); ``live`` (B,) the trials
    that still have a live model (the others are left as they are).
    """
    b, n_act = mu.shape
    qp0 = kf.params.qp0
    dead = ~np.isfinite(kf.q_hat).all(axis=1) | kf.diverged
    mu = np.where(dead.reshape(b, n_act), 0.0, mu)  # a model that diverged has μ = 0
    tot = mu.sum(axis=1, keepdims=True)
    live = live & (tot[:, 0] > 0.0)
    mu = mu / np.where(tot > 0.0, tot, 1.0)
    c_bar, mix = mixing_probabilities(mu, trans)
    # reference attitude: the most probable model of each trial
    q = np.where(dead[:, None], np.array([0.0, 0.0, 0.0, 1.0]), kf.q_hat).reshape(b, n_act, 4)
    best = mu.argmax(axis=1)
    q_ref = q[np.arange(b), best][:, None]  # (B, 1, 4)
    rel = attitude_error(q_ref, q).reshape(-1, 3)  # δθ_i = Log(Ĉ_refᵀ Ĉ_i)
    x = np.concatenate([rel, kf.b_hat, kf.p_hat], axis=1)
    kq = (kappas * qp0)[None, :, None, None]  # κ_j q_p0, 1/s
    u = unit_q[:, None]  # (B, 1, 15, 15)
    cov = (kf.P.reshape(b, n_act, 15, 15) - kq * u).reshape(-1, 15, 15)  # P̃_i = P_i − κ_i q_p0 U
    x[dead] = 0.0  # μ_i = 0 for these: neutral values keep NaN out of the sums
    cov[dead] = 0.0
    x0, p0 = mix_moments(x.reshape(b, n_act, 15), cov.reshape(b, n_act, 15, 15), mix)
    p0 += kq * u  # + κ_j q_p0 U_j
    p0 = 0.5 * (p0 + np.swapaxes(p0, -1, -2))
    q0 = quat_mul(q_ref, quat_exp(x0[..., 0:3])).reshape(-1, 4)  # Ĉ0_j = Ĉ_ref Exp(δθ0_j)
    q0 /= np.linalg.norm(q0, axis=-1, keepdims=True)
    rows = np.repeat(live, n_act)
    kf.q_hat[rows] = q0[rows]
    kf.b_hat[rows] = x0[..., 3:6].reshape(-1, 3)[rows]
    kf.p_hat[rows] = x0[..., 6:15].reshape(-1, 9)[rows]
    p_all = kf.P
    p_all[rows] = p0.reshape(-1, 15, 15)[rows]
    kf.P = p_all
    kf.diverged[rows] = False  # every model restarts from the mixture
    return np.where(live[:, None], c_bar, mu)


def imm_filter_reference(cfg: Config, data: ScenarioData, prm: ImmConfig) -> MethodOutput:
    """:func:`imm_filter` driven from numpy: per mixing interval :func:`mix_bank`, the filter's
    :meth:`~TransferAlignmentKF.step` over the interval, :func:`update_model_probabilities` per
    epoch, :func:`unit_calibration_noise`; :func:`combine` every ``BLOCK`` epochs. The reference
    the compiled bank is tested against (equal to rounding); about six times as slow."""
    kappas = action_values(cfg)
    n_act = kappas.size
    b, n = data.n_trials, data.n_epochs
    trans = transition_matrix(n_act, prm.p_stay, prm.switching)
    bank = new_filter(cfg, data, n_copies=n_act)  # row = trial * A + model
    kappa_rows = np.tile(kappas, b)
    mu = np.full((b, n_act), 1.0 / n_act)
    live = np.ones(b, dtype=bool)
    alive = np.ones((b, n), dtype=bool)  # trial still has a live model at the epoch
    est = np.full((b, n, 16), np.nan)
    probs = np.empty((b, n, n_act))
    buf_est = np.empty((b, n_act, BLOCK, 16))
    buf_w = np.empty((b, n_act, BLOCK))
    buf_start = 0
    cov = CovarianceRecorder(cfg, b)
    bank_cov = CovarianceRecorder(cfg, b * n_act)
    unit_q: np.ndarray | None = None
    m = prm.mix_every
    for k0 in range(0, n, m):
        k1 = min(n, k0 + m)
        c_bar = mu
        if unit_q is not None and live.any():
            c_bar = mix_bank(bank, mu, trans, kappas, unit_q, live)
        rec = step_bank(bank, data, k0, k1, kappa_rows, bank_cov)
        ll = rec.loglik.reshape(b, n_act, k1 - k0)
        for k in range(k1 - k0):
            new = update_model_probabilities(c_bar, ll[:, :, k])  # μ_j ∝ Λ_j c̄_j
            live &= new.sum(axis=1) > 0.0  # all models dead at once: the trial has diverged
            mu = np.where(live[:, None], new, mu)
            c_bar = mu  # no transition inside a mixing interval
            probs[:, k0 + k] = mu
            alive[:, k0 + k] = live
        # buffer the bank's posterior estimates; combine every BLOCK epochs
        bank_est = rec.est.reshape(b, n_act, k1 - k0, 16)
        if cov.sampled_in(k0, k1).size:  # the mixture covariance at the sampled epochs
            w_blk = np.moveaxis(probs[:, k0:k1], 2, 1)
            clean = neutral_dead(bank_est)
            record_bank_covariance(cov, bank_cov, k0, clean, w_blk, combine(clean, w_blk))
        for k in range(k1 - k0):
            j = k0 + k - buf_start
            buf_est[:, :, j] = bank_est[:, :, k]
            buf_w[:, :, j] = probs[:, k0 + k, :]
            if j + 1 == BLOCK or k0 + k + 1 == n:
                _flush(est, buf_est[:, :, : j + 1], buf_w[:, :, : j + 1], buf_start)
                buf_start = k0 + k + 1
        # U of the last propagation, at the most probable model's ω̂ and p̂
        finite = np.isfinite(rec.rate[:, -1]).all(axis=1) & np.isfinite(bank.p_hat).all(axis=1)
        best = np.arange(b) * n_act + np.where(finite.reshape(b, n_act), mu, -1.0).argmax(axis=1)
        rate, p_hat, ok = rec.rate[best, -1], bank.p_hat[best], finite[best]
        unit_q = unit_calibration_noise(
            bank.params.dt, np.where(ok[:, None], rate, 0.0), np.where(ok[:, None], p_hat, 0.0)
        )
    est[~alive] = np.nan
    return _output(prm, kappas, est, probs, ~live, cov.cov)


def _flush(est: np.ndarray, bank_est: np.ndarray, w: np.ndarray, start: int) -> None:
    """Combine buffered bank estimates (B, A, n, 16) with weights (B, A, n) into ``est``."""
    e = neutral_dead(bank_est)  # diverged models: weight 0, neutral values
    est[:, start : start + e.shape[2]] = combine(e, w)
