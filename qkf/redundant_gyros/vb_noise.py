r"""Variational-Bayes noise scales of the gyro calibration UKF, projected onto κ: a classical
baseline for the gyro policies that tries to identify the episode's noise levels
(docs/redundant_gyros.md, "VB noise scales").

Model. The filter assumes ``w_k ~ N(0, Q₀_k)``, ``Q₀_k = diag(q²) Δt_k`` (κ = 1), and
measurement variance ``R₀(x)`` (:mod:`~qkf.redundant_gyros.ukf`); the episode's truth has
``Q = θ_Q Q₀`` and ``R = θ_R R₀`` with unknown scales (``gyro_noise_levels`` draws both).
The posterior of each scale is inverse-Gamma, ``IG(α, β)``, with the point estimate
``θ̂ = E[θ⁻¹]⁻¹ = β / α`` (as the VB adaptive filters plug it in, Särkkä & Nummenmaa, IEEE
TAC 54(3), 2009). A filter with ``(θ_Q Q₀, θ_R R₀)`` has the gain of one with
``(θ_Q/θ_R · Q₀, R₀)`` (the gain depends on the ratio; the prior aside), so the one lever of
the gym carries both estimates:

    κ_{t+1} = clip(θ̂_Q / θ̂_R, κ_min, κ_max).

The κ-filter's covariance is that filter's over ``θ_R``: in the truth's scale ``P = θ̂_R P_f``.

Statistics of one epoch ``k`` (the expectations under the filter's Gaussian posterior; ``Φ = I``
so ``P⁻_k = P_{k−1} + Q_k``, ``Q_k = κ Q₀_k`` the filter's, ``Δx̂_k = x̂_k − x̂_{k−1}``):

* process noise, the lag-one smoothed ``w_k = x_k − x_{k−1}``: with ``G_k = Q_k (P⁻_k)⁻¹``
  (``Cov(w, x_k) = Q_k``; ``z_k`` sees ``x_k`` only),

      E[w wᵀ | z_{1:k}] = θ̂_R (Q_k − G_k Q_k + G_k P_k G_kᵀ) + G_k Δx̂_k Δx̂_kᵀ G_kᵀ,
      s_Q,k = Σ_i E[w wᵀ]_ii / Q₀_k,ii                      (its mean is 4 θ_Q under the model)

  always ≥ 0, unlike Sage–Husa's ``Δx̂Δx̂ᵀ + P_k − P_{k−1}`` (:mod:`.sage_husa`); while ``P ≫ Q``
  it stays at the filter's own ``Q`` and moves only as the innovations carry evidence;
* measurement noise, the post-fit residual with ``H_k = ∂h/∂x`` at ``x̂_k``,

      s_R,k = ((z_k − h(x̂_k))² + θ̂_R H_k P_k H_kᵀ) / R₀(x̂_{k−1})   (mean θ_R, linear model)

  (``R₀`` at the predicted state, where the filter evaluates it), compiled
  (:func:`measurement_statistic`; its numpy reference is ``tests/vb_noise_numpy.py``): the
  environment ``qkf/RedundantGyroCalibration-v4`` observes ``θ̂_R`` from it too.

The scales' posteriors are updated once per decision period from the period's epochs, with a
forgetting factor ``ρ = 2^(−1/h)`` per period (half-life ``h`` periods, Särkkä & Nummenmaa's
``α ← ρ α``, ``β ← ρ β``):

    α_Q ← ρ α_Q + 2 n_t,   β_Q ← ρ β_Q + ½ Σ_k s_Q,k        (4 states: n/2 = 2 per epoch)
    α_R ← ρ α_R + ½ n_t,   β_R ← ρ β_R + ½ Σ_k s_R,k        (n_t epochs run in the period)

from priors worth one period of epochs ``P``: ``α_Q = 2P``, ``β_Q = 2P κ_0``, ``α_R = P/2``,
``β_R = P/2`` (θ_Q at the start κ_0, θ_R at the assumed 1). One update per period is one
fixed-point (EM) iteration of the VB scheme per period, the filter's κ held inside it as every
method and policy of the gym holds it: the statistics use the κ and ``θ̂_R`` that ran.
``adapt`` chooses the scales adapted: ``"q"`` (``θ̂_R = 1``), ``"r"`` (``θ̂_Q = κ_0``: the
R-only VB of Särkkä & Nummenmaa on this lever), ``"qr"`` both, ``"none"`` the constant κ_0
(so the tuned rule nests every constant κ). :func:`tune_on` picks the settings from a grid
of 176 points on tuning episodes; the filter is the compiled UKF of the environments
(:class:`~qkf.redundant_gyros.nis_adaptive.EpisodeBatch` with ``keep_cov``).

Known behaviour (measured, docs/redundant_gyros.md): the R scale is identified within a few
per cent over an episode; the Q scale is not. Once the filter has converged ``G ≈ Q/P⁻ ~ 10⁻³``,
so the data enter ``E[w wᵀ]`` with weight ``G² ~ 10⁻⁶`` (``θ̂_Q`` moves by about 10⁻⁶ relative
over a 600-s episode with the truth at 9 × κ_0): the EM of a process noise far below the
state's uncertainty. The tuning therefore picks the R scale alone on every gyro family.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Literal

import numpy as np

from qkf.core.jit import kernel_jit
from qkf.redundant_gyros.batched_ukf import BatchedUKF
from qkf.redundant_gyros.nis_adaptive import EpisodeBatch
from qkf.redundant_gyros.ukf import UkfSetup
from qkf.redundant_gyros.ukf_compiled import CompiledSetup, Geometry, noise_variance

Adapt = Literal["none", "q", "r", "qr"]
ADAPTS: tuple[Adapt, ...] = ("q", "r", "qr")
"""The adapted scales of the tuning grid (``"none"`` once per start)."""
HALF_LIVES = (1.0, 3.0, 10.0, 30.0, float("inf"))
"""The tuning grid's half-lives of the scales' posteriors, decision periods (``inf``: no
forgetting, the levels held for the episode); with the action set's κ (11) as starts and the
three ``ADAPTS``, plus the 11 constants: 176 points."""


@dataclass(frozen=True)
class VbRule:
    """The rule's settings: the scales adapted (``adapt``), the half-life of their posteriors
    (``halflife``, decision periods; ``inf``: no forgetting), the start ``kappa0``."""

    adapt: Adapt
    halflife: float
    kappa0: float


def process_statistic(
    est: np.ndarray,
    cov: np.ndarray,
    x_prev: np.ndarray,
    p_prev: np.ndarray,
    q_step: np.ndarray,
    kappa: np.ndarray,
    theta_r: np.ndarray,
) -> np.ndarray:
    """``s_Q`` (n, P) of each epoch of a period (module docstring), NaN where not run.

    ``est`` (n, P, 4), ``cov`` (n, P, 4, 4): the estimate and updated covariance per epoch (NaN
    where not run); ``x_prev`` (n, 4), ``p_prev`` (n, 4, 4): before the period's first epoch;
    ``q_step`` (n, P, 4): ``Q₀_k,ii = q²_i Δt_k``; ``kappa`` (n,) the κ the period ran with;
    ``theta_r`` (n,) the ``θ̂_R`` it ran with."""
    x_before = np.concatenate([x_prev[:, None, :], est[:, :-1, :]], axis=1)  # x̂_{k−1}
    p_before = np.concatenate([p_prev[:, None, :, :], cov[:, :-1, :, :]], axis=1)  # P_{k−1}
    q = kappa[:, None, None] * q_step  # (n, P, 4): diag of Q_k
    ran = _ran(est, cov)
    eye = np.eye(4)
    # P⁻ of the epochs not run: the identity, so that the solve below stays defined
    p_minus = np.where(ran[:, :, None, None], p_before + q[..., None] * eye, eye)
    g = np.swapaxes(np.linalg.solve(p_minus, q[..., None] * eye), -1, -2)  # G = Q (P⁻)⁻¹
    dx = np.where(ran[:, :, None], est - x_before, 0.0)
    gdx = np.einsum("...ij,...j->...i", g, dx)
    p_k = np.where(ran[:, :, None, None], cov, 0.0)
    gpg = np.einsum("...ij,...jl,...il->...i", g, p_k, g)  # diag of G P_k Gᵀ
    g_diag = np.diagonal(g, axis1=2, axis2=3)
    smoothed = theta_r[:, None, None] * (q - g_diag * q + gpg) + gdx * gdx  # diag of E[w wᵀ]
    return np.where(ran, np.sum(smoothed / q_step, axis=2), np.nan)


def measurement_statistic(
    setup: UkfSetup,
    est: np.ndarray,
    cov: np.ndarray,
    x_prev: np.ndarray,
    theta_r: np.ndarray,
    z: np.ndarray,
    rate: np.ndarray,
) -> np.ndarray:
    """``s_R`` (n, P) of each epoch of a period (module docstring), NaN where not run:
    ``est``, ``cov``, ``x_prev``, ``theta_r`` as :func:`process_statistic`'s, ``z`` (n, P)
    the calibrated gyro's readings and ``rate`` (n, P, 3) the triad rates (deg/s). Compiled
    (:func:`_post_fit_rows`); its numpy reference is ``tests/vb_noise_numpy.py``."""
    out = np.empty(z.shape)
    theta = np.asarray(theta_r, dtype=float)
    _post_fit_rows(est, cov, x_prev, theta, z, rate, CompiledSetup.of(setup).geometry, out)
    return out


@kernel_jit(nrt=True, fastmath=False)
def _post_fit_rows(
    est: np.ndarray,
    cov: np.ndarray,
    x_prev: np.ndarray,
    theta_r: np.ndarray,
    z: np.ndarray,
    rate: np.ndarray,
    geometry: Geometry,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``out[b, i] = ((z − h(x̂_i))² + θ̂_R H P_i Hᵀ) / R₀(x̂_{i−1})`` (module docstring) with
    ``h(x) = (1 − λ) w̄ᵀ ω̂ − b``, ``H = [−1, −w̄ᵀω̂, −(1 − λ) uᵀω̂, −(1 − λ) vᵀω̂]`` and
    ``R₀(x) = σ² + ‖(1 − λ) w̄ᵀ G_H⁻¹ diag(s_H)‖²`` (:mod:`~qkf.redundant_gyros.ukf`), NaN
    where the epoch did not run; serial over the rows (a period is a few thousand epochs).
    ``geometry``: :attr:`CompiledSetup.geometry`."""
    w, u, v, _, _, _, _ = geometry
    jac = np.empty(4)
    for b in range(est.shape[0]):
        before = x_prev[b]
        for i in range(est.shape[1]):
            x, p = est[b, i], cov[b, i]
            ran = True
            for j in range(4):
                if not np.isfinite(x[j]):
                    ran = False
                for m in range(4):
                    if not np.isfinite(p[j, m]):
                        ran = False
            if not ran:
                out[b, i] = np.nan
                continue
            r = rate[b, i]
            w_rate = 0.0
            u_rate = 0.0
            v_rate = 0.0
            for m in range(3):
                w_rate += (w[m] - x[2] * u[m] - x[3] * v[m]) * r[m]
                u_rate += u[m] * r[m]
                v_rate += v[m] * r[m]
            h = (1.0 - x[1]) * w_rate - x[0]
            jac[0] = -1.0
            jac[1] = -w_rate
            jac[2] = -(1.0 - x[1]) * u_rate
            jac[3] = -(1.0 - x[1]) * v_rate
            hph = 0.0
            for j in range(4):
                for m in range(4):
                    hph += jac[j] * p[j, m] * jac[m]
            r0 = noise_variance(before, geometry)
            resid = z[b, i] - h
            out[b, i] = (resid * resid + theta_r[b] * hph) / r0
            before = x


def period_measurement_statistic(
    ukf: BatchedUKF, epoch: np.ndarray, x_prev: np.ndarray, theta_r: np.ndarray
) -> np.ndarray:
    """:func:`measurement_statistic` of the period ``ukf`` has just run (its UKF keeping each
    epoch's covariance and estimate), over its ``epoch`` (n, P)
    (:meth:`~qkf.redundant_gyros.batched_ukf.BatchedUKF.period_epochs`), from the estimates
    ``x_prev`` (n, 4) before it, with ``θ̂_R`` ``theta_r`` (n,)."""
    rows = np.arange(ukf.n)[:, None]
    z, rate = ukf.z[rows, epoch], ukf.rate[rows, epoch]
    return measurement_statistic(ukf.setup, ukf.est, ukf.cov, x_prev, theta_r, z, rate)


Q_HALF_DOF = 2.0
"""Half the entries an epoch's process statistic sums (the four states)."""
R_HALF_DOF = 0.5
"""Half the entries an epoch's measurement statistic sums (one reading)."""


@dataclass
class ScalePosterior:
    """The inverse-Gamma posteriors ``IG(α, β)`` (n,) of one noise scale over ``n`` episodes
    (module docstring); ``half_dof`` is half the entries an epoch's statistic sums
    (:data:`Q_HALF_DOF`, :data:`R_HALF_DOF`)."""

    alpha: np.ndarray
    beta: np.ndarray
    half_dof: float

    @classmethod
    def prior(cls, n: int, mean: float, epochs: float, half_dof: float) -> ScalePosterior:
        """A prior at ``mean`` worth ``epochs`` epochs of statistics, for ``n`` episodes."""
        post = cls(np.empty(n), np.empty(n), half_dof)
        post.restart(np.arange(n), mean, epochs)
        return post

    def restart(self, rows: np.ndarray, mean: float, epochs: float) -> None:
        """Rows ``rows`` back to :meth:`prior`'s ``(mean, epochs)``."""
        alpha = self.half_dof * epochs
        self.alpha[rows], self.beta[rows] = alpha, alpha * mean

    @property
    def estimate(self) -> np.ndarray:
        """``θ̂ = E[θ⁻¹]⁻¹ = β/α`` (n,)."""
        return np.asarray(self.beta / self.alpha)

    def update(self, stats: np.ndarray, rho: float) -> np.ndarray:
        """Forget by ``rho`` (``α ← ρ α``, ``β ← ρ β``), then add a period's statistics (n, P)
        (NaN: epochs not run); the estimate ``θ̂ = β/α`` (n,) after it."""
        ran = np.isfinite(stats)
        self.alpha = rho * self.alpha + self.half_dof * ran.sum(axis=1)
        self.beta = rho * self.beta + 0.5 * np.where(ran, stats, 0.0).sum(axis=1)
        return self.estimate


def _ran(est: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(n, P): the epochs run (finite estimate and covariance)."""
    return np.isfinite(est).all(axis=2) & np.isfinite(cov).all(axis=(2, 3))


def run_rule_on(b: EpisodeBatch, rule: VbRule) -> np.ndarray:
    """``J`` per episode of the rule on episodes loaded into ``b`` (its UKF keeping each
    epoch's covariance and estimate: ``EpisodeBatch.of_episodes(..., keep_cov=True)``);
    ``inf`` where the filter fails."""
    return run_rule_traced(b, rule)[0]


def run_rule_traced(b: EpisodeBatch, rule: VbRule) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`run_rule_on`, and the scale estimates ``θ̂_Q``, ``θ̂_R`` (n, T) after each of the
    T decision periods."""
    ukf = b.ukf
    b.restart_for_covariances("VB")
    lo, hi = b.kappa_range()
    per = float(ukf.period)
    post_q = ScalePosterior.prior(ukf.n, rule.kappa0, per, Q_HALF_DOF)
    post_r = ScalePosterior.prior(ukf.n, 1.0, per, R_HALF_DOF)
    rho = 2.0 ** (-1.0 / rule.halflife)
    kappa = np.full(ukf.n, rule.kappa0)
    theta_q, theta_r = kappa.copy(), np.ones(ukf.n)
    total = np.zeros(ukf.n)
    n_periods = -(-ukf.n_steps // ukf.period)
    trace_q, trace_r = np.empty((ukf.n, n_periods)), np.empty((ukf.n, n_periods))
    for t in range(n_periods):
        x_prev, p_prev = ukf.x.copy(), ukf.p.copy()
        k0, _ = ukf.advance(kappa)
        total += ukf.settled_square(k0, b.settled)
        if rule.adapt != "none":
            epoch = ukf.period_epochs(k0)
            q_step = ukf.nominal_process_noise(epoch)
            s_q = process_statistic(ukf.est, ukf.cov, x_prev, p_prev, q_step, kappa, theta_r)
            s_r = period_measurement_statistic(ukf, epoch, x_prev, theta_r)
            if "q" in rule.adapt:
                theta_q = post_q.update(s_q, rho)
            if "r" in rule.adapt:
                theta_r = post_r.update(s_r, rho)
            kappa = np.clip(theta_q / theta_r, lo, hi)
        trace_q[:, t], trace_r[:, t] = theta_q, theta_r
    return b.criterion(total), trace_q, trace_r


def tune_on(batch: EpisodeBatch) -> tuple[VbRule, float]:
    """The grid point (the constants, then :data:`ADAPTS` × :data:`HALF_LIVES` × the action
    set as starts) with the lowest mean ``J`` over the episodes of ``batch``, and that mean
    (the first such point on ties: a constant before an adapting rule that equals it)."""
    kappas = batch.actions()
    constants = (VbRule("none", 1.0, k0) for k0 in kappas)
    grid = itertools.product(ADAPTS, HALF_LIVES, kappas)
    adapting = (VbRule(adapt, h, k0) for adapt, h, k0 in grid)
    return batch.best_rule(itertools.chain(constants, adapting), run_rule_on)


__all__ = [
    "ADAPTS",
    "HALF_LIVES",
    "Q_HALF_DOF",
    "R_HALF_DOF",
    "ScalePosterior",
    "VbRule",
    "measurement_statistic",
    "period_measurement_statistic",
    "process_statistic",
    "run_rule_on",
    "run_rule_traced",
    "tune_on",
]
