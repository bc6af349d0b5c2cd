r"""MMAE: a bank of parallel filters, one per κ of the action set (docs/methods.md).

Model probabilities follow the innovation likelihood of each filter::

    log w_i,k = log w_i,k−1 + ℓ_i,k − log Σ_j exp(…),   ℓ = −½ (νᵀ S⁻¹ ν + log det S)

with a floor on each weight (renormalised) so that no model is locked out for good. The output
is the weighted estimate: ``b̂``, ``p̂`` as weighted means, the attitude as the weighted mean
rotation vector about the most probable filter's attitude. The filters do not interact.

:func:`run_mmae` runs the whole bank (A × B filters) in one compiled call
(:func:`~qkf.transfer_alignment.methods.bank_compiled.run_bank`): the filter epoch, the weight
recursion and the combination per trial and epoch, trials in parallel. Its reference is the same
method in numpy, ``tests/mmae_numpy.py`` (``update_log_weights``, ``combine``,
``mixture_covariance`` and ``run_mmae_reference``, the bank driven from numpy in blocks of
epochs); the tests check the compiled bank against it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from qkf.transfer_alignment.adaptive import MmaeConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.methods.bank_compiled import BankRun, run_bank
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    action_values,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder
from qkf.transfer_alignment.scenario import ScenarioData


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
