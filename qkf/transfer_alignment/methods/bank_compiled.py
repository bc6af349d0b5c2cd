r"""The κ bank of MMAE and IMM compiled (numba): one parallel call runs the whole bank.

Both methods run A filters per trial, one per κ of the action set (rows ``trial · A + model`` of
one :class:`~qkf.transfer_alignment.filter.TransferAlignmentKF`), and combine them every
epoch. Driven from numpy, the work around the filter cost more than the filter: IMM called the
filter once per epoch (its mixing sits between two epochs), and every call opened a parallel
region and allocated the work arrays of every row again; both methods spent about as long again
in numpy on the weights, the combination (scipy ``Rotation``) and the mixing. Here each trial
runs all its epochs in one compiled routine (:func:`_bank_trial`), trials in parallel
(``prange``); per trial and epoch ``k``::

    IMM, first epoch of a mixing interval (k > 0):  mix the bank            mix_trial
    every model j: the filter's epoch k (update, records, propagation)     kernel._epoch_loop
    ℓ_j = −½ (νᵀ S⁻¹ ν + log det S)_j     (0 without a measurement, −∞ once diverged)
    MMAE: log w_j ← log w_j + ℓ_j − log Σ_i exp(…), floored                 mmae_log_weights
    IMM:  μ_j ∝ exp(ℓ_j) c̄_j                                               imm_probabilities
    x̂_k = the models' a-posteriori estimates combined with w (μ)           combine_one
    sampled epochs: P = Σ_j w_j (P_j + d_j d_jᵀ) about x̂_k                 mixture_covariance_one
    IMM, last epoch of a mixing interval: U at the most probable model     unit_noise

The filter epoch is the kernel's own per-trial routine (``kernel._epoch_loop``, with its
``_scale_factors`` and ``_make_scratch``), called with inputs and records of the kernel's
types (one epoch, every row of the bank) and the filter's own constants, so every model computes
the bits that :meth:`TransferAlignmentKF.step` computes (a test checks it). This couples the
module to those private routines and to the filter's private state (``_pt``, ``_d``,
``_kernel_constants``): a change of them must be followed here. The data is read from the
trials' (B, N, ·) arrays, not copied per model.

Each routine has a numpy reference, which stays the documented and tested definition
(``tests/test_bank_compiled.py`` checks each pair, the pieces batched by
``tests/bank_reference.py``, and both methods end to end):

========================  ===========================================================
compiled (here)           numpy reference (``tests/mmae_numpy.py``, ``tests/imm_numpy.py``)
========================  ===========================================================
mmae_log_weights          ``mmae_numpy.update_log_weights``
imm_probabilities         ``imm_numpy.update_model_probabilities``
combine_one               ``mmae_numpy.combine``
mixture_covariance_one    ``mmae_numpy.mixture_covariance``
mix_trial                 ``imm_numpy.mix_bank``
unit_noise                ``imm_numpy.unit_calibration_noise``
run_bank                  ``mmae_numpy.run_mmae_reference``, ``imm_numpy.imm_filter_reference``
========================  ===========================================================

The results equal the numpy ones to rounding: sums run in another order (with the kernels'
fast-math flags, :mod:`qkf.core.jit`), the mixing runs in the kernel's scaled units, ``exp`` and
``log`` are LLVM's instead of numpy's, ``A = (I + K(p̂))⁻¹`` is the kernel's adjugate instead of
LAPACK's inverse, and rotations use :mod:`qkf.core.quat` instead of scipy's ``Rotation``. The
IMM's model probabilities amplify that rounding (module doc of
:mod:`~qkf.transfer_alignment.methods.imm`).

Units SI: rad, rad/s, s; ``q_p`` in 1/s; ``U`` in s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from qkf.core.jit import kernel_array, kernel_jit, row_loops
from qkf.core.quat import quat_mul_exp, relative_rotvec
from qkf.transfer_alignment import kernel as _ta_kernel
from qkf.transfer_alignment.filter import SensorData, TransferAlignmentKF
from qkf.transfer_alignment.model_compiled import a_omega, rate_estimate

UNIT_Q_ORDER = 4
"""Highest total power of ``[ω̂×] Δt`` in :func:`unit_noise` (as in the numpy reference)."""


class BankData(NamedTuple):
    """The trials' sensor data (SI), read by every model of the trial."""

    gyro: np.ndarray  # (B, N, 3) ω̃, rad/s
    ads_q: np.ndarray  # (B, N, 4) ADS attitude, scalar-last
    ads_rate: np.ndarray  # (B, N, 3) ADS rate, rad/s
    has_meas: np.ndarray  # (B, N) bool


class BankSettings(NamedTuple):
    """What the bank does besides filtering."""

    imm: bool  # IMM (mixing, μ recursion) instead of MMAE (floored log-weight recursion)
    kappas: np.ndarray  # (A,) κ_j of the models
    kq: np.ndarray  # (A,) κ_j q_p0, 1/s
    trans: np.ndarray  # (A, A) IMM switching matrix Π_ij (unused by MMAE)
    trans_c: float  # Π = c 1 1ᵀ + R: c (split_transitions)
    trans_r: np.ndarray  # (A, A) R
    floor: float  # MMAE weight floor (0: none)
    mix_every: int  # IMM mixing interval M ≥ 1, epochs
    slot: np.ndarray  # (N,) int64: index of epoch k among the sampled covariance epochs, or −1
    inv_d: np.ndarray  # (15,) 1/d_i, d the kernel's state scales: P̃ = D⁻¹ P D⁻¹, D = diag(d)
    inv_dd: np.ndarray  # (15, 15) 1/(d_i d_j)
    dt: float  # Δt, s
    coef_g: np.ndarray  # (5,) series coefficients of U (unit_noise_coefficients)
    coef_tt: np.ndarray  # (5, 5)


class BankOutputs(NamedTuple):
    """Written by :func:`run_bank_trials`."""

    est: np.ndarray  # (B, N, 16) combined a-posteriori estimate (IMM: NaN once diverged)
    weights: np.ndarray  # (B, N, A) MMAE weights w / IMM probabilities μ after each epoch
    alive: np.ndarray  # (B, N) bool: the trial still has a live model (IMM)
    cov: np.ndarray  # (B, M, 15, 15) mixture covariance at the sampled epochs (NaN-filled)
    live: np.ndarray  # (B,) bool: alive after the last epoch (IMM)


class _Work(NamedTuple):
    """Per-trial work arrays of the bank (contents undefined between uses)."""

    mu: np.ndarray  # (A,) IMM μ
    c_bar: np.ndarray  # (A,) IMM c̄
    new: np.ndarray  # (A,) IMM μ of the update
    log_w: np.ndarray  # (A,) MMAE log w
    w: np.ndarray  # (A,) weights of this epoch
    ll: np.ndarray  # (A,) ℓ
    mu_m: np.ndarray  # (A,) μ with diverged models removed, renormalised
    dead: np.ndarray  # (A,) bool: diverged model (mixing), used model (mixture covariance)
    finite: np.ndarray  # (A,) bool
    est: np.ndarray  # (A, 16) models' estimates, neutral where diverged
    rel: np.ndarray  # (A, 3) rotation vectors about a reference attitude
    x: np.ndarray  # (A, 15) x̂_i = (δθ_i, b̂_i, p̂_i)
    y: np.ndarray  # (A, 15) x̂_i − x̄
    y0: np.ndarray  # (A, 15) y0_j = Σ_i μ_i|j y_i
    centre: np.ndarray  # (15,) x̄
    yt: np.ndarray  # (A, 15) D⁻¹ y_i, then D⁻¹ y0_j
    ysum: np.ndarray  # (15,) Σ_i μ_i y_i
    second: np.ndarray  # (A, 225) S̃_i = P̃_i − κ_i q_p0 Ũ + ỹ_i ỹ_iᵀ (15 × 15, row-major)
    tsum: np.ndarray  # (225,) Σ_i μ_i S̃_i
    acc: np.ndarray  # (225,)
    ut: np.ndarray  # (225,) Ũ = D⁻¹ U D⁻¹
    yy: np.ndarray  # (225,) an outer product ỹ ỹᵀ
    d: np.ndarray  # (A, 15) mixture-covariance spreads
    est_mix: np.ndarray  # (16,) combined estimate
    q_ref: np.ndarray  # (4,)
    u: np.ndarray  # (15, 15) U
    a: np.ndarray  # (3, 3) A = (I + K(p̂))⁻¹
    w3: np.ndarray  # (3,) ω̂ of rate_estimate (not used)
    zero3: np.ndarray  # (3,) zeros
    zero9: np.ndarray  # (9,) zeros
    aom: np.ndarray  # (3, 9) A Ω(ω̂)
    m3: np.ndarray  # (3, 3) A Ω Ωᵀ Aᵀ
    pw: np.ndarray  # (UNIT_Q_ORDER + 1, 3, 3) (−W)ⁿ
    g: np.ndarray  # (3, 3)
    left: np.ndarray  # (3, 3)
    u_tt: np.ndarray  # (3, 3)


@kernel_jit(nrt=True)
def _make_work(n_act: int) -> _Work:
    """Work arrays of one trial's bank of ``n_act`` models."""
    return _Work(
        np.empty(n_act),
        np.empty(n_act),
        np.empty(n_act),
        np.empty(n_act),
        np.empty(n_act),
        np.empty(n_act),
        np.empty(n_act),
        np.zeros(n_act, dtype=np.bool_),
        np.zeros(n_act, dtype=np.bool_),
        np.empty((n_act, 16)),
        np.empty((n_act, 3)),
        np.empty((n_act, 15)),
        np.empty((n_act, 15)),
        np.empty((n_act, 15)),
        np.empty(15),
        np.empty((n_act, 15)),
        np.empty(15),
        np.empty((n_act, 225)),
        np.empty(225),
        np.empty(225),
        np.empty(225),
        np.empty(225),
        np.empty((n_act, 15)),
        np.empty(16),
        np.empty(4),
        np.zeros((15, 15)),
        np.empty((3, 3)),
        np.empty(3),
        np.zeros(3),
        np.zeros(9),
        np.empty((3, 9)),
        np.empty((3, 3)),
        np.empty((UNIT_Q_ORDER + 1, 3, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
    )


# ---- model probabilities ------------------------------------------------------------------------


@kernel_jit()
def mmae_log_weights(log_w: np.ndarray, ll: np.ndarray, floor: float, w: np.ndarray) -> None:
    r"""One step of the MMAE weight recursion, in place on ``log_w`` (A,); ``w`` (A,) scratch.

    With ``alive_i = (ℓ_i, log w_i finite)``::

        λ_i = log w_i + ℓ_i (alive) or −∞,   w_i = exp(λ_i − max λ) / Σ exp(…)
        floor > 0:  w_i ← max(w_i, floor) (alive) or 0,  renormalised
        log w_i ← log w_i

    A diverged model (non-finite ℓ) has weight 0 for good; with no live model at all every
    weight is NaN (as in the numpy reference, ``mmae_numpy.update_log_weights``).
    """
    n = log_w.shape[0]
    top = -np.inf
    for i in range(n):
        if np.isfinite(ll[i]) and np.isfinite(log_w[i]):
            w[i] = log_w[i] + ll[i]  # λ_i = log w_i + ℓ_i
        else:
            w[i] = -np.inf
        if w[i] > top:
            top = w[i]
    if top == -np.inf:  # no live model: λ − max λ = −∞ − (−∞) is NaN in the reference
        for i in range(n):
            log_w[i] = np.nan
        return
    tot = 0.0
    for i in range(n):
        w[i] = np.exp(w[i] - top)  # exp(λ_i − max λ)
        tot += w[i]
    for i in range(n):
        w[i] /= tot
    if floor > 0.0:
        tot = 0.0
        for i in range(n):
            if np.isfinite(ll[i]) and np.isfinite(log_w[i]):
                if w[i] < floor:
                    w[i] = floor  # max(w_i, floor)
            else:
                w[i] = 0.0
            tot += w[i]
        for i in range(n):
            w[i] /= tot
    for i in range(n):
        log_w[i] = np.log(w[i])


@kernel_jit()
def imm_probabilities(c_bar: np.ndarray, ll: np.ndarray, out: np.ndarray) -> float:
    r"""``μ_j ∝ Λ_j c̄_j``, ``Λ_j = exp(ℓ_j)``, in the log domain, into ``out`` (A,); returns
    ``Σ_j μ_j`` (1, or 0 when no model is alive).

    A model with a non-finite ``ℓ`` or ``c̄ = 0`` gets ``μ = 0``; with none alive, all zeros
    (as ``imm_numpy.update_model_probabilities``)::

        λ_j = log c̄_j + ℓ_j,   μ_j = exp(λ_j − max λ) / Σ_i exp(λ_i − max λ)
    """
    n = c_bar.shape[0]
    top = -np.inf
    for j in range(n):
        if np.isfinite(ll[j]) and c_bar[j] > 0.0:
            out[j] = np.log(c_bar[j]) + ll[j]  # λ_j = log c̄_j + ℓ_j
        else:
            out[j] = -np.inf
        if out[j] > top:
            top = out[j]
    shift = top if np.isfinite(top) else 0.0
    tot = 0.0
    for j in range(n):
        out[j] = np.exp(out[j] - shift)
        tot += out[j]
    if not tot > 0.0:
        for j in range(n):
            out[j] = 0.0
        return 0.0
    for j in range(n):
        out[j] /= tot  # μ_j = exp(λ_j − max λ) / Σ
    return 1.0


# ---- combination of the bank ---------------------------------------------------------------------


@kernel_jit()
def _first_argmax(w: np.ndarray) -> int:
    """Index of the first largest entry (the first NaN if there is one, as ``np.argmax``)."""
    best = 0
    for i in range(w.shape[0]):
        if np.isnan(w[i]):
            return i
        if w[i] > w[best]:
            best = i
    return best


@kernel_jit()
def combine_one(est: np.ndarray, w: np.ndarray, out: np.ndarray, rel: np.ndarray) -> None:
    r"""Weighted estimate of a bank at one epoch: ``est`` (A, 16) the models' estimates (finite:
    diverged ones neutral), ``w`` (A,) weights summing to 1, into ``out`` (16,); ``rel`` (A, 3)
    scratch. As ``mmae_numpy.combine``::

        b̂ = Σ_j w_j b̂_j,   p̂ = Σ_j w_j p̂_j
        δθ_j = Log(Ĉ_refᵀ Ĉ_j),   Ĉ = Ĉ_ref Exp(Σ_j w_j δθ_j)   (normalised)

    with ``Ĉ_ref`` the estimate of the most probable model (the first, on a tie).
    """
    n = w.shape[0]
    best = _first_argmax(w)
    for c in range(4, 16):
        v = 0.0
        for j in range(n):
            v += w[j] * est[j, c]  # Σ_j w_j x̂_j
        out[c] = v
    for j in range(n):
        relative_rotvec(est[best], est[j], rel[j])  # δθ_j = Log(Ĉ_refᵀ Ĉ_j)
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for j in range(n):
        m0 += w[j] * rel[j, 0]
        m1 += w[j] * rel[j, 1]
        m2 += w[j] * rel[j, 2]
    rel[0, 0] = m0  # the mean rotation vector (row 0 is no longer needed)
    rel[0, 1] = m1
    rel[0, 2] = m2
    quat_mul_exp(est[best], rel[0], out)  # Ĉ = Ĉ_ref Exp(Σ w δθ), normalised


@kernel_jit()
def mixture_covariance_one(
    est: np.ndarray,
    cov: np.ndarray,
    w: np.ndarray,
    est_mix: np.ndarray,
    out: np.ndarray,
    d: np.ndarray,
    used: np.ndarray,
) -> None:
    r"""Covariance (15, 15) of a bank about its combined estimate, into ``out``, as
    ``mmae_numpy.mixture_covariance``::

        P = Σ_j w_j (P_j + d_j d_jᵀ),   d_j = (Log(Ĉ_mixᵀ Ĉ_j), b̂_j − b̂_mix, p̂_j − p̂_mix)

    over the models that are used (``w_j > 0``, finite estimate and covariance); NaN if none is
    or the combined estimate is not finite. ``est`` (A, 16), ``cov`` (A, 15, 15) SI, ``w`` (A,),
    ``est_mix`` (16,); ``d`` (A, 15) and ``used`` (A,) bool scratch.
    """
    n = w.shape[0]
    ok_mix = True
    for c in range(16):
        if not np.isfinite(est_mix[c]):
            ok_mix = False
    any_use = False
    for a in range(n):
        use = w[a] > 0.0
        for c in range(16):
            if not np.isfinite(est[a, c]):
                use = False
        for i in range(15):
            for j in range(15):
                if not np.isfinite(cov[a, i, j]):
                    use = False
        used[a] = use
        any_use = any_use or use
        if use and ok_mix:
            relative_rotvec(est_mix, est[a], d[a])  # δθ_a = Log(Ĉ_mixᵀ Ĉ_a)
            for c in range(3, 15):
                d[a, c] = est[a, c + 1] - est_mix[c + 1]  # Δb_a, Δp_a
        else:
            for c in range(15):
                d[a, c] = 0.0
    for i in range(15):
        for j in range(15):
            out[i, j] = 0.0
    for a in range(n):
        if not used[a]:
            continue
        wa = w[a]
        for i in range(15):
            for j in range(15):
                out[i, j] += wa * (cov[a, i, j] + d[a, i] * d[a, j])  # w (P + d dᵀ)
    if not (ok_mix and any_use):
        for i in range(15):
            for j in range(15):
                out[i, j] = np.nan
        return
    for i in range(15):
        for j in range(i + 1, 15):
            v = 0.5 * (out[i, j] + out[j, i])
            out[i, j] = v
            out[j, i] = v


# ---- IMM: calibration noise and mixing ---------------------------------------------------------


def unit_noise_coefficients(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The series coefficients of :func:`unit_noise` for the step ``dt`` (s), as the numpy
    reference computes them: ``g_n = Δtⁿ⁺² / (n+2)!`` (n ≤ 4) and
    ``c_nk = Δtⁿ⁺ᵏ⁺³ / ((n+1)! (k+1)! (n+k+3))`` (n + k ≤ 4, else 0)."""
    fact = [float(math.factorial(i)) for i in range(UNIT_Q_ORDER + 3)]
    g = np.array([dt ** (n + 2) / fact[n + 2] for n in range(UNIT_Q_ORDER + 1)])
    c = np.zeros((UNIT_Q_ORDER + 1, UNIT_Q_ORDER + 1))
    for n in range(UNIT_Q_ORDER + 1):
        for k in range(UNIT_Q_ORDER + 1 - n):
            c[n, k] = dt ** (n + k + 3) / (fact[n + 1] * fact[k + 1] * (n + k + 3))
    return g, c


@kernel_jit()
def unit_noise(
    dt: float,
    coef_g: np.ndarray,
    coef_tt: np.ndarray,
    rate: np.ndarray,
    p_hat: np.ndarray,
    u: np.ndarray,
    wk: _Work,
) -> bool:
    r"""``U = ∂Q_d/∂q_p`` (15, 15, s) at the rate ``rate`` (rad/s) and ``A = (I + K(p̂))⁻¹``, into
    ``u``, as ``imm_numpy.unit_calibration_noise``. With ``W = [ω̂×]``, ``M = A Ω Ωᵀ Aᵀ``::

        U_θθ = Σ_{n+m ≤ 4} (−W)ⁿ M Wᵐ Δtⁿ⁺ᵐ⁺³ / ((n+1)! (m+1)! (n+m+3))     (symmetrised)
        U_θp = −Σ_n (−W)ⁿ Δtⁿ⁺² / (n+2)! · A Ω,    U_pθ = U_θpᵀ,    U_pp = Δt I

    and zeros elsewhere; ``coef_g``, ``coef_tt`` the coefficients of the two series
    (:func:`unit_noise_coefficients` of ``dt``). False (``u`` NaN) if ``I + K(p̂)`` is singular.
    """
    a, aom, m3, pw, g, left, u_tt = wk.a, wk.aom, wk.m3, wk.pw, wk.g, wk.left, wk.u_tt
    for i in range(15):
        for j in range(15):
            u[i, j] = 0.0
    if not rate_estimate(rate, wk.zero3, p_hat, a, wk.w3):  # A = (I + K(p̂))⁻¹
        for i in range(15):
            for j in range(15):
                u[i, j] = np.nan
        return False
    a_omega(a, rate, aom)  # A Ω(ω̂)
    for i in range(3):
        for j in range(3):
            v = 0.0
            for l in range(9):
                v += aom[i, l] * aom[j, l]
            m3[i, j] = v  # M = A Ω Ωᵀ Aᵀ
    # (−W)ⁿ, n = 0 … UNIT_Q_ORDER;  −W = −[ω̂×] = [−ω̂×]
    w0, w1, w2 = -rate[0], -rate[1], -rate[2]
    for i in range(3):
        for j in range(3):
            pw[0, i, j] = 1.0 if i == j else 0.0
    for n in range(1, UNIT_Q_ORDER + 1):
        for i in range(3):
            p0, p1, p2 = pw[n - 1, i, 0], pw[n - 1, i, 1], pw[n - 1, i, 2]
            # row i of (−W)ⁿ⁻¹ times [w×] = [[0, −w2, w1], [w2, 0, −w0], [−w1, w0, 0]]
            pw[n, i, 0] = p1 * w2 - p2 * w1
            pw[n, i, 1] = -p0 * w2 + p2 * w0
            pw[n, i, 2] = p0 * w1 - p1 * w0
    # G = Σ_n (−W)ⁿ Δtⁿ⁺² / (n+2)!
    for i in range(3):
        for j in range(3):
            g[i, j] = 0.0
    for n in range(UNIT_Q_ORDER + 1):
        c = coef_g[n]  # Δtⁿ⁺² / (n+2)!
        for i in range(3):
            for j in range(3):
                g[i, j] += pw[n, i, j] * c
    # U_θθ = Σ_{n+k ≤ 4} c_nk (−W)ⁿ M ((−W)ᵏ)ᵀ,  c_nk = Δtⁿ⁺ᵏ⁺³ / ((n+1)! (k+1)! (n+k+3))
    for i in range(3):
        for j in range(3):
            u_tt[i, j] = 0.0
    for n in range(UNIT_Q_ORDER + 1):
        for i in range(3):
            for j in range(3):
                v = 0.0
                for l in range(3):
                    v += pw[n, i, l] * m3[l, j]
                left[i, j] = v  # (−W)ⁿ M
        for k in range(UNIT_Q_ORDER + 1 - n):
            c = coef_tt[n, k]  # Δtⁿ⁺ᵏ⁺³ / ((n+1)! (k+1)! (n+k+3))
            for i in range(3):
                for j in range(3):
                    v = 0.0
                    for l in range(3):
                        v += left[i, l] * pw[k, j, l]
                    u_tt[i, j] += c * v
    for i in range(3):
        for j in range(3):
            u[i, j] = 0.5 * (u_tt[i, j] + u_tt[j, i])
        for l in range(9):
            v = 0.0
            for k in range(3):
                v += g[i, k] * aom[k, l]
            u[i, 6 + l] = -v  # U_θp = −G A Ω
            u[6 + l, i] = -v
    for l in range(9):
        u[6 + l, 6 + l] = dt  # U_pp = Δt I
    return True


@kernel_jit()
def _outer15(y: np.ndarray, out: np.ndarray) -> None:
    """``y yᵀ`` of ``y`` (15,) into ``out`` (225,), row-major: ``out[15 a + b] = y_a y_b``."""
    for a in range(15):
        ya = y[a]
        for b in range(15):
            out[15 * a + b] = ya * y[b]


@kernel_jit()
def mix_trial(
    state: _ta_kernel.FilterState,
    r0: int,
    mu: np.ndarray,
    trans: np.ndarray,
    trans_c: float,
    trans_r: np.ndarray,
    kq: np.ndarray,
    u: np.ndarray,
    inv_d: np.ndarray,
    inv_dd: np.ndarray,
    live: bool,
    c_bar: np.ndarray,
    wk: _Work,
) -> bool:
    r"""Mix the predicted states of one trial's bank (rows ``r0 … r0 + A − 1`` of ``state``) in
    place, as ``imm_numpy.mix_bank``; ``c̄`` (A,) into ``c_bar``. Returns whether it mixed.

    ``μ`` (A,) the model probabilities; ``Π`` (A, A) as ``trans`` and split as
    ``Π_ij = c + R_ij`` (``trans_c`` = c, ``trans_r`` = R: diagonal for uniform switching,
    tridiagonal for neighbours); ``kq`` (A,) κ_j q_p0 (1/s); ``u`` (15, 15) the trial's ``U`` (s);
    ``inv_d`` (15,) ``1/d_i`` and ``inv_dd`` (15, 15) ``1/(d_i d_j)`` of the kernel's state
    scales ``d``. A diverged model has ``μ = 0``; ``μ`` is renormalised
    over the others. A trial that is not ``live`` or has no live model is left as it is and gets
    the renormalised ``μ`` as ``c̄``. Otherwise::

        c̄_j = Σ_i Π_ij μ_i,   μ_i|j = Π_ij μ_i / c̄_j   (δ_ij where c̄_j = 0)
        x̂_i = (Log(Ĉ_refᵀ Ĉ_i), b̂_i, p̂_i)   (0 for a diverged model; Ĉ_ref: most probable)
        y_i = x̂_i − x̄,   x̄ = Σ_i x̂_i / A,    y0_j = Σ_i μ_i|j y_i
        S_i = P_i − κ_i q_p0 U + y_i y_iᵀ      (P_i − κ_i q_p0 U := 0 for a diverged model)
        P0_j = Σ_i μ_i|j S_i − y0_j y0_jᵀ + κ_j q_p0 U
        Ĉ0_j = Ĉ_ref Exp(δθ0_j) (normalised),  (b̂0_j, p̂0_j) = x̄ + y0_j

    and every model restarts (``diverged`` cleared). The covariances are mixed in the kernel's
    scaled units (``P̃ = D⁻¹ P D⁻¹``, ``ỹ = D⁻¹ y``, ``Ũ = D⁻¹ U D⁻¹``: the sums are linear, so
    the same up to rounding), and ``Σ_i μ_i|j S_i`` as ``(c Σ_i μ_i S_i + Σ_i R_ij μ_i S_i) /
    c̄_j``: A + (non-zeros of R) sums of a 15 × 15 matrix instead of A² (uniform switching: one
    pass per model). Every entry (a, b) is computed by the same operations as (b, a), so
    ``P̃0_j`` stays exactly symmetric.
    """
    n = mu.shape[0]
    q_hat, b_hat, p_hat, pt, diverged = (
        state.q_hat,
        state.b_hat,
        state.p_hat,
        state.pt,
        state.diverged,
    )
    mu_m, dead, x, y, y0, centre = wk.mu_m, wk.dead, wk.x, wk.y, wk.y0, wk.centre
    second, tsum, acc, ut, yt, ysum = wk.second, wk.tsum, wk.acc, wk.ut, wk.yt, wk.ysum
    yy = wk.yy
    q_ref = wk.q_ref
    # μ of a diverged model = 0, renormalised
    tot = 0.0
    for i in range(n):
        r = r0 + i
        bad = diverged[r]
        for c in range(4):
            if not np.isfinite(q_hat[r, c]):
                bad = True
        dead[i] = bad
        mu_m[i] = 0.0 if bad else mu[i]
        tot += mu_m[i]
    scale = tot if tot > 0.0 else 1.0
    for i in range(n):
        mu_m[i] /= scale
    if not (live and tot > 0.0):
        for j in range(n):
            c_bar[j] = mu_m[j]
        return False
    # c̄_j = Σ_i Π_ij μ_i
    for j in range(n):
        v = 0.0
        for i in range(n):
            v += trans[i, j] * mu_m[i]
        c_bar[j] = v
    # x̂_i = (δθ_i, b̂_i, p̂_i) about the most probable model's attitude
    best = _first_argmax(mu_m)
    for c in range(4):
        q_ref[c] = q_hat[r0 + best, c]
    for i in range(n):
        r = r0 + i
        if dead[i]:
            for c in range(15):
                x[i, c] = 0.0
            continue
        relative_rotvec(q_ref, q_hat[r], x[i])  # δθ_i = Log(Ĉ_refᵀ Ĉ_i)
        for c in range(3):
            x[i, 3 + c] = b_hat[r, c]
        for c in range(9):
            x[i, 6 + c] = p_hat[r, c]
    # x̄ and y_i = x̂_i − x̄ (SI), ỹ_i = D⁻¹ y_i
    for c in range(15):
        v = 0.0
        for i in range(n):
            v += x[i, c]
        centre[c] = v / n
    for i in range(n):
        for c in range(15):
            y[i, c] = x[i, c] - centre[c]
            yt[i, c] = y[i, c] * inv_d[c]
    # Ũ = D⁻¹ U D⁻¹ and S̃_i = P̃_i − κ_i q_p0 Ũ + ỹ_i ỹ_iᵀ, 15 × 15 matrices stored flat
    for a in range(15):
        for b in range(15):
            ut[15 * a + b] = u[a, b] * inv_dd[a, b]
    for i in range(n):
        s_i = second[i]
        _outer15(yt[i], yy)  # ỹ_i ỹ_iᵀ
        if dead[i]:
            for e in range(225):
                s_i[e] = yy[e]  # P̃_i − κ_i q_p0 Ũ := 0
        else:
            p_i = pt[r0 + i].reshape(225)
            kqi = kq[i]
            for e in range(225):
                s_i[e] = (p_i[e] - kqi * ut[e]) + yy[e]
    # the part of Π common to all pairs: T̃ = Σ_i μ_i S̃_i,  Y = Σ_i μ_i y_i
    for c in range(15):
        v = 0.0
        for i in range(n):
            v += mu_m[i] * y[i, c]
        ysum[c] = v
    for e in range(225):
        tsum[e] = 0.0
    for i in range(n):
        m = mu_m[i]
        if m != 0.0:
            s_i = second[i]
            for e in range(225):
                tsum[e] += m * s_i[e]
    for j in range(n):
        p_j = pt[r0 + j].reshape(225)
        cj = c_bar[j]
        kqj = kq[j]
        y_j = yt[j]
        # the models i with R_ij μ_i ≠ 0: how many, and the last
        n_nz = 0
        i_nz = 0
        for i in range(n):
            if trans_r[i, j] * mu_m[i] != 0.0:
                n_nz += 1
                i_nz = i
        if cj > 0.0 and n_nz <= 1:
            # one pass: P̃0_j = (c T̃ + R_ij μ_i S̃_i) / c̄_j − ỹ0_j ỹ0_jᵀ + κ_j q_p0 Ũ
            inv = 1.0 / cj
            m = trans_r[i_nz, j] * mu_m[i_nz]
            s_i = second[i_nz]
            for c in range(15):
                y0[j, c] = (trans_c * ysum[c] + m * y[i_nz, c]) * inv
                y_j[c] = y0[j, c] * inv_d[c]  # ỹ0_j (ỹ_j is no longer needed)
            _outer15(y_j, yy)  # ỹ0_j ỹ0_jᵀ
            for e in range(225):
                p_j[e] = ((trans_c * tsum[e] + m * s_i[e]) * inv - yy[e]) + kqj * ut[e]
        else:
            if cj > 0.0:
                # Σ_i μ_i|j S̃_i = (c T̃ + Σ_i R_ij μ_i S̃_i) / c̄_j, and likewise y0_j
                inv = 1.0 / cj
                for e in range(225):
                    acc[e] = trans_c * tsum[e]
                for c in range(15):
                    y0[j, c] = trans_c * ysum[c]
                for i in range(n):
                    m = trans_r[i, j] * mu_m[i]
                    if m != 0.0:
                        s_i = second[i]
                        for e in range(225):
                            acc[e] += m * s_i[e]
                        for c in range(15):
                            y0[j, c] += m * y[i, c]
                for e in range(225):
                    acc[e] *= inv
                for c in range(15):
                    y0[j, c] *= inv
            else:  # c̄_j = 0: μ_i|j = δ_ij, the model keeps its own state
                s_j = second[j]
                for e in range(225):
                    acc[e] = s_j[e]
                for c in range(15):
                    y0[j, c] = y[j, c]
            for c in range(15):
                y_j[c] = y0[j, c] * inv_d[c]  # ỹ0_j (ỹ_j is no longer needed)
            _outer15(y_j, yy)  # ỹ0_j ỹ0_jᵀ
            for e in range(225):
                # P̃0_j = Σ_i μ_i|j S̃_i − ỹ0_j ỹ0_jᵀ + κ_j q_p0 Ũ
                p_j[e] = (acc[e] - yy[e]) + kqj * ut[e]
        r = r0 + j
        for c in range(15):
            x[j, c] = y0[j, c] + centre[c]  # x̂0_j (x̂_j is no longer needed)
        quat_mul_exp(q_ref, x[j], q_hat[r])  # Ĉ0_j = Ĉ_ref Exp(δθ0_j), normalised
        for c in range(3):
            b_hat[r, c] = x[j, 3 + c]
        for c in range(9):
            p_hat[r, c] = x[j, 6 + c]
        diverged[r] = False  # every model restarts from the mixture
    return True


def split_transitions(trans: np.ndarray) -> tuple[float, np.ndarray]:
    """``Π = c 1 1ᵀ + R`` with ``c`` the smallest off-diagonal entry (``R`` exactly zero where
    ``Π_ij = c``: off the diagonal for uniform switching); returns ``(c, R)``."""
    trans = np.asarray(trans, dtype=float)
    off = trans[~np.eye(trans.shape[0], dtype=bool)]
    c = float(off.min()) if off.size else 0.0
    return c, np.ascontiguousarray(trans - c)


# ---- the bank over all epochs ------------------------------------------------------------------


@kernel_jit(nrt=True)
def _bank_trial(
    t: int,
    state: _ta_kernel.FilterState,
    inp: _ta_kernel.Inputs,
    c: _ta_kernel.Constants,
    rec: _ta_kernel.Records,
    rec_cov: _ta_kernel.Records,
    data: BankData,
    st: BankSettings,
    out: BankOutputs,
) -> None:
    """Every epoch of trial ``t``'s bank (module doc): rows ``t·A … t·A + A − 1`` of ``state``,
    ``inp``, ``rec`` and ``rec_cov`` (the kernel's one-epoch inputs and records, without and with
    the covariance), data row ``t``, outputs row ``t``."""
    n_act = st.kappas.shape[0]
    r0 = t * n_act
    n_ep = data.gyro.shape[1]
    sc = _ta_kernel._scale_factors(c)
    s = _ta_kernel._make_scratch(6 if c.use_rate else 3)
    wk = _make_work(n_act)
    mu, c_bar, log_w, ll, est, w = wk.mu, wk.c_bar, wk.log_w, wk.ll, wk.est, wk.w
    for j in range(n_act):
        for l in range(9):
            inp.kappa[r0 + j, 0, l] = st.kappas[j]  # q_p = κ_j q_p0
        mu[j] = 1.0 / n_act
        log_w[j] = -np.log(n_act)
    live = True
    have_u = False
    for k in range(n_ep):
        # ---- IMM: mix at the start of each mixing interval (from the second on) ---------------
        if st.imm and k % st.mix_every == 0:
            if have_u:  # c̄ of the mixing (the renormalised μ where the trial is not mixed)
                mix_trial(
                    state,
                    r0,
                    mu,
                    st.trans,
                    st.trans_c,
                    st.trans_r,
                    st.kq,
                    wk.u,
                    st.inv_d,
                    st.inv_dd,
                    live,
                    c_bar,
                    wk,
                )
            else:
                for j in range(n_act):
                    c_bar[j] = mu[j]
        # ---- every model: the filter's epoch k ------------------------------------------------
        slot = st.slot[k]
        rk = rec_cov if slot >= 0 else rec
        for j in range(n_act):
            r = r0 + j
            for i in range(3):
                inp.gyro[r, 0, i] = data.gyro[t, k, i]
                inp.ads_rate[r, 0, i] = data.ads_rate[t, k, i]
            for i in range(4):
                inp.ads_q[r, 0, i] = data.ads_q[t, k, i]
            inp.has_meas[r, 0] = data.has_meas[t, k]
            _ta_kernel._epoch_loop(r, state, inp, c, rk, sc, s)
        # ---- ℓ_j = −½ (νᵀ S⁻¹ ν + log det S); the estimates, neutral where diverged -----------
        for j in range(n_act):
            r = r0 + j
            ok = True
            for i in range(16):
                est[j, i] = rk.est[r, 0, i]
                if not np.isfinite(est[j, i]):
                    ok = False
            nis = rk.stats[r, 0, 2]
            if not ok:
                ll[j] = -np.inf
                for i in range(16):
                    est[j, i] = 0.0
                est[j, 3] = 1.0
            elif np.isnan(nis):
                ll[j] = 0.0  # no measurement
            else:
                ll[j] = -0.5 * (nis + rk.stats[r, 0, 3])
        # ---- model probabilities -------------------------------------------------------------
        if st.imm:
            if imm_probabilities(c_bar, ll, wk.new) > 0.0 and live:
                for j in range(n_act):
                    mu[j] = wk.new[j]
            else:
                live = False  # all models dead at once: the trial has diverged (and is frozen)
            for j in range(n_act):
                c_bar[j] = mu[j]  # no transition inside a mixing interval
                w[j] = mu[j]
            out.alive[t, k] = live
        else:
            mmae_log_weights(log_w, ll, st.floor, w)
            for j in range(n_act):
                w[j] = np.exp(log_w[j])
        for j in range(n_act):
            out.weights[t, k, j] = w[j]
        # ---- combined estimate and, at the sampled epochs, its covariance ---------------------
        combine_one(est, w, wk.est_mix, wk.rel)
        for i in range(16):
            out.est[t, k, i] = wk.est_mix[i] if (live or not st.imm) else np.nan
        if slot >= 0:
            mixture_covariance_one(
                est, rk.cov[r0 : r0 + n_act, 0], w, wk.est_mix, out.cov[t, slot], wk.d, wk.dead
            )
        # ---- IMM: U of the last propagation of a mixing interval, at the most probable model --
        if st.imm and ((k + 1) % st.mix_every == 0 or k + 1 == n_ep):
            best = -1
            top = -np.inf
            for j in range(n_act):
                r = r0 + j
                fin = True
                for i in range(3):
                    if not np.isfinite(rk.rate[r, 0, i]):
                        fin = False
                for i in range(9):
                    if not np.isfinite(state.p_hat[r, i]):
                        fin = False
                v = mu[j] if fin else -1.0
                if best < 0 or v > top:
                    best = j
                    top = v
                wk.finite[j] = fin
            if wk.finite[best]:
                unit_noise(
                    st.dt,
                    st.coef_g,
                    st.coef_tt,
                    rk.rate[r0 + best, 0],
                    state.p_hat[r0 + best],
                    wk.u,
                    wk,
                )
            else:
                unit_noise(st.dt, st.coef_g, st.coef_tt, wk.zero3, wk.zero9, wk.u, wk)
            have_u = True
    out.live[t] = live


run_bank_trials = row_loops(_bank_trial, "data.gyro.shape[0]").parallel
""":func:`_bank_trial` for every trial (its arguments after the trial index), trials in
parallel."""


# ---- Python side --------------------------------------------------------------------------------


def _records(rows: int, with_cov: bool) -> _ta_kernel.Records:
    """One-epoch kernel records for ``rows`` rows (with the covariance, or without)."""
    return _ta_kernel.Records(
        est=np.empty((rows, 1, 16)),
        var=np.empty((rows, 1, 15)),
        cov=np.empty((rows, 1 if with_cov else 0, 15, 15)),
        dx=np.empty((rows, 1, 15)),
        innov=np.empty((rows, 1, 6)),
        stats=np.empty((rows, 1, 5)),
        rate=np.empty((rows, 1, 3)),
    )


@dataclass
class BankRun:
    """What :func:`run_bank` returns (B trials, N epochs, A models)."""

    est: np.ndarray  # (B, N, 16) combined estimate (IMM: NaN where the trial had diverged)
    weights: np.ndarray  # (B, N, A) MMAE weights / IMM model probabilities after each epoch
    alive: np.ndarray  # (B, N) bool: IMM trial still alive (all True for MMAE)
    live: np.ndarray  # (B,) bool: IMM trial alive at the end (all True for MMAE)


def run_bank(
    bank: TransferAlignmentKF,
    sensors: SensorData,
    kappas: np.ndarray,
    cov_epochs: np.ndarray,
    cov_out: np.ndarray,
    *,
    trans: np.ndarray | None = None,
    floor: float = 0.0,
    mix_every: int = 1,
) -> BankRun:
    """Run the bank ``bank`` (rows ``trial · A + model``, model ``j`` with ``κ = kappas[j]``) over
    all epochs of ``sensors`` (``gyro``, ``ads_rate`` (B, N, 3) rad/s, ``ads_q`` (B, N, 4),
    ``has_meas`` (N,) or (B, N): simulated or recorded data) in one compiled call; ``bank`` is
    left at the end of the run.

    ``trans`` given: IMM with switching matrix ``Π`` and mixing interval ``mix_every``; else
    MMAE with weight floor ``floor``. The mixture covariance at the epochs ``cov_epochs`` (M,)
    goes to ``cov_out`` (B, M, 15, 15), in place.
    """
    kappas = np.ascontiguousarray(kappas, dtype=float)
    n_act = kappas.size
    gyro = np.ascontiguousarray(sensors.gyro, dtype=float)
    b, n = gyro.shape[:2]
    if bank.n_trials != b * n_act:
        raise ValueError(
            f"a bank of {n_act} models per trial for {b} trials needs {b * n_act} rows"
        )
    rows = b * n_act
    slot = np.full(n, -1, dtype=np.int64)
    epochs = np.asarray(cov_epochs, dtype=np.int64)
    inside = epochs < n
    slot[epochs[inside]] = np.arange(epochs.size)[inside]
    imm = trans is not None
    trans = np.ascontiguousarray(trans if trans is not None else np.eye(n_act), dtype=float)
    trans_c, trans_r = split_transitions(trans)
    coef_g, coef_tt = unit_noise_coefficients(float(bank.params.dt))
    settings = BankSettings(
        imm=imm,
        kappas=kappas,
        kq=kappas * float(bank.params.qp0),
        trans=trans,
        trans_c=trans_c,
        trans_r=trans_r,
        floor=float(floor),
        mix_every=int(mix_every),
        slot=slot,
        inv_d=1.0 / bank._d,
        inv_dd=1.0 / np.outer(bank._d, bank._d),
        dt=float(bank.params.dt),
        coef_g=coef_g,
        coef_tt=coef_tt,
    )
    data = BankData(
        gyro=gyro,
        ads_q=np.ascontiguousarray(sensors.ads_q, dtype=float),
        ads_rate=np.ascontiguousarray(sensors.ads_rate, dtype=float),
        has_meas=kernel_array(sensors.has_meas, bool, (b, n)),
    )
    out = BankOutputs(
        est=np.empty((b, n, 16)),
        weights=np.empty((b, n, n_act)),
        alive=np.ones((b, n), dtype=bool),
        cov=cov_out,
        live=np.ones(b, dtype=bool),
    )
    inputs = _ta_kernel.Inputs(
        gyro=np.empty((rows, 1, 3)),
        ads_q=np.empty((rows, 1, 4)),
        ads_rate=np.empty((rows, 1, 3)),
        has_meas=np.empty((rows, 1), dtype=bool),
        kappa=np.empty((rows, 1, 9)),
        sigma_a=np.ascontiguousarray(bank.sigma_a, dtype=float),
        q_scale=np.ones((rows, 2)),
    )
    run_bank_trials(
        _ta_kernel.FilterState(*bank._kernel_state()),
        inputs,
        _ta_kernel.Constants(*bank._kernel_constants()),  # those TransferAlignmentKF.step uses
        _records(rows, False),
        _records(rows, True),
        data,
        settings,
        out,
    )
    return BankRun(est=out.est, weights=out.weights, alive=out.alive, live=out.live)
