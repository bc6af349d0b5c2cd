r"""IMM: interacting multiple models over the κ bank (docs/methods.md).

The models are the κ values of the action set; model ``j`` is the filter with
``q_p = κ_j q_p0``. The model index follows a Markov chain with switching matrix
``Π_ij = P(model j at k | model i at k − 1)``: ``Π_ii = p_stay`` and the rest of each row
spread uniformly over the other models (``switching: uniform``, the default) or split between
the neighbours ``i ± 1`` in the ordered action set (``switching: neighbours``). One cycle, for
every trial::

    c̄_j     = Σ_i Π_ij μ_i                                        predicted model probability
    μ_i|j   = Π_ij μ_i / c̄_j                                      mixing probabilities
    x̂0_j    = Σ_i μ_i|j x̂_i                                       mixed mean
    P0_j    = Σ_i μ_i|j (P_i + (x̂_i − x̂0_j)(x̂_i − x̂0_j)ᵀ)          mixed covariance
    (filter every model j from (x̂0_j, P0_j) with its own κ_j)
    Λ_j     = exp(ℓ_j),   ℓ_j = −½ (νᵀ S⁻¹ ν + log det S)_j          model likelihood
    μ_j     ∝ Λ_j c̄_j                                             model probability

Unlike the MMAE bank, whose weights can lock in, the transition mass ``1 − p_stay`` feeds every
model each cycle and the mixing restarts every model from the common mixture, so all models
stay alive without a weight floor. With ``Π = I`` the probability recursion is the MMAE one
without floor (a test checks it).

**On the error-state filter.** The compiled filter runs, for one epoch, the update at ``k`` and
the propagation to ``k + 1`` in one call, so the bank is mixed on its *predicted* states, at the
start of the next epoch's call. The state of model ``i`` is the estimate ``(Ĉ_i, b̂_i, p̂_i)``
and the covariance ``P_i`` of its error state. The mixing works on the 15-vector
``x̂_i = (Log(Ĉ_refᵀ Ĉ_i), b̂_i, p̂_i)``, where the attitude is a rotation vector about a
reference attitude ``Ĉ_ref`` (the most probable model's, as in the MMAE ``combine``); the mixed
attitude is ``Ĉ0_j = Ĉ_ref Exp(δθ0_j)`` and the attitude spread enters ``P0_j`` through the
rotation-vector differences (small-angle: the models differ by arcseconds, and the change of the
attitude-error frame between models, ``I + O(δθ)``, is neglected as in the filter's reset).

Because mixing happens after the propagation ``k → k + 1``, every predicted ``P_i`` already
holds its own calibration process noise ``κ_i q_p0 U_i``, where ``U_i = Q_d(q_p = 1 /s,
σ_v = σ_u = 0)`` is the part of ``Q_d`` per unit calibration density at model ``i``'s ``ω̂`` and
``A`` (``Q_d`` is linear in ``q_p``). Standard IMM mixes posteriors and then predicts with
``Q_j``; the equivalent on predicted states swaps the calibration noise::

    P̃_i  = P_i − κ_i q_p0 U_i                                      (predicted, without q_p)
    P0_j = Σ_i μ_i|j (P̃_i + d_ij d_ijᵀ) + κ_j q_p0 U_j,   d_ij = x̂_i − x̂0_j

``P̃_i`` is the prediction with zero calibration noise (positive semi-definite); the rest of
``P_i`` (the gyro noise terms and the correlated rate-noise terms) does not depend on κ and is
mixed as it is. ``U`` is evaluated once per trial, at the most probable model's ``ω̂`` and
``p̂`` (the models differ by parts in 10⁶), in closed form as a series in ``[ω̂×] Δt``
(``unit_noise`` of :mod:`.bank_compiled`). Spreads are taken between predicted means instead
of ``Φ`` times the spreads of posterior means: equal to first order (the models' ``Φ`` differ
only through their ``ω̂``, ``A``).

**Mixing interval.** ``mix_every`` = M ≥ 1 epochs: between mixings the models run as
independent filters (``Π = I``: ``c̄ = μ``) in one compiled call, and ``p_stay`` is the
probability of staying over one mixing interval. Default M = 1 (every epoch).

**Output.** ``μ``-weighted combination of the models' a-posteriori estimates (MMAE's
``combine``). κ reported per epoch: ``exp(Σ_j μ_j log κ_j)`` (as MMAE). The combined
covariance ``Σ_j μ_j (P_j + spread)`` carries the *arithmetic* mean ``Σ_j μ_j κ_j`` of the
calibration noise; it is logged as ``kappa_arith``.

**Divergence.** A model with a non-finite likelihood gets ``μ = 0``; the next mixing gives it a
fresh mixed initial condition and it runs again. A trial counts as diverged once all of its
models have diverged at the same epoch; it is frozen from then on.

**Implementation.** :func:`imm_filter` runs the whole bank in one compiled call
(:func:`~qkf.transfer_alignment.methods.bank_compiled.run_bank`): per trial and epoch the
mixing, the filter epoch of every model, the probability update, the combination and ``U``,
trials in parallel. Its reference is the same algebra in numpy, ``tests/imm_numpy.py``
(``mixing_probabilities``, ``mix_moments``, ``update_model_probabilities``,
``unit_calibration_noise``, ``mix_bank`` and ``imm_filter_reference``, the method driven from
numpy epoch by epoch); the tests check the compiled bank against it. The two agree to
rounding, which the model probabilities amplify (a log-likelihood ``ℓ`` of about 75 is a
difference of large log-determinants, and its rounding feeds the recursion every epoch):
perturbing the mixed covariances of the numpy reference itself by one unit in the last place
moves the probabilities by up to 1e-10 and ``p̂`` by up to 3e-14 over 3600 epochs (``paper``
and ``thermal_snap_random``, 8 trials), as far as the compiled bank differs from it.

Units SI throughout: rad, rad/s, s; ``q_p`` in 1/s; ``U`` in s (per 1/s of density).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from qkf.transfer_alignment.adaptive import ImmConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    action_values,
    uses_settings,
)
from qkf.transfer_alignment.methods.mmae import run_compiled_bank
from qkf.transfer_alignment.scenario import ScenarioData

Switching = Literal["uniform", "neighbours"]


def transition_matrix(n_models: int, p_stay: float, switching: Switching = "uniform") -> np.ndarray:
    """Markov switching matrix ``Π`` (A, A), rows summing to 1: ``Π_ij = P(j at k | i at k−1)``.

    ``uniform``: ``Π_ii = p_stay``, ``Π_ij = (1 − p_stay)/(A − 1)`` for ``j ≠ i``.
    ``neighbours``: ``1 − p_stay`` split equally between ``i − 1`` and ``i + 1`` (all of it to
    the one neighbour at either end of the ordered action set).
    """
    if n_models < 2:
        raise ValueError("an IMM needs at least two models")
    if not 0.0 < p_stay <= 1.0:
        raise ValueError(f"p_stay must be in (0, 1], got {p_stay}")
    off = 1.0 - p_stay
    if switching == "uniform":
        pi = np.full((n_models, n_models), off / (n_models - 1))
    elif switching == "neighbours":
        pi = np.zeros((n_models, n_models))
        for i in range(n_models):
            nb = [j for j in (i - 1, i + 1) if 0 <= j < n_models]
            pi[i, nb] = off / len(nb)
    else:
        raise ValueError(f"unknown switching {switching!r}")
    np.fill_diagonal(pi, p_stay)
    return pi


@uses_settings("imm", ImmConfig)
def run_imm(cfg: Config, data: ScenarioData) -> MethodOutput:
    """The ``imm`` method: :func:`imm_filter` with the config's settings (``adaptive.imm``)."""
    return imm_filter(cfg, data, cfg.adaptive.imm)


def imm_filter(cfg: Config, data: ScenarioData, prm: ImmConfig) -> MethodOutput:
    """The IMM over the κ action set, all trials at once (bank of A × B filters), with the
    settings ``prm`` (``ImmConfig``: ``p_stay``, ``switching``, ``mix_every``), compiled.

    Logs the model probabilities per epoch (``probabilities``, (B, N, A)) and the arithmetic
    mean ``Σ μ_j κ_j`` (``kappa_arith``, (B, N))."""
    kappas = action_values(cfg)
    trans = transition_matrix(kappas.size, prm.p_stay, prm.switching)
    _, run, cov = run_compiled_bank(cfg, data, kappas, trans=trans, mix_every=prm.mix_every)
    return _output(prm, kappas, run.est, run.weights, ~run.live, cov)


def _output(
    prm: ImmConfig,
    kappas: np.ndarray,
    est: np.ndarray,
    probs: np.ndarray,
    diverged: np.ndarray,
    cov: np.ndarray,
) -> MethodOutput:
    """The method's output from the bank's combined estimates and probabilities (B, N, A)."""
    log_k = np.log(kappas)
    kappa = np.exp(probs @ log_k)  # probability-weighted geometric mean of the bank's κ
    kappa_arith = probs @ kappas
    notes = {
        "imm": f"p_stay = {prm.p_stay:g}, {prm.switching} switching, "
        f"mixing every {prm.mix_every} epoch(s)"
    }
    return MethodOutput(
        est=est,
        diverged=diverged,
        kappa=kappa,
        logs={"probabilities": probs, "kappa_arith": kappa_arith},
        notes=notes,
        cov=cov,
    )
