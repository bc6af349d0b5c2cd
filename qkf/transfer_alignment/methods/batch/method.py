"""The ``batch`` method: the driver of the compiled estimator and its :class:`MethodOutput`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.core.jit import kernel_array
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput
from qkf.transfer_alignment.methods.batch.sensitivity import N_Y
from qkf.transfer_alignment.methods.batch.solver import solve_trials
from qkf.transfer_alignment.methods.batch.structs import Constants, Inputs, Outputs
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import ScenarioData

MAX_ITERATIONS = 10
"""Gauss–Newton passes at most (re-propagation each)."""
STEP_TOLERANCE = 1e-2
"""Converged when every component of the step is below this fraction of its 1-σ."""


@dataclass(frozen=True)
class BatchSolution:
    """What the batch estimator found for B trials (SI).

    ``est`` (B, N, 16) and ``cov`` (B, M, 15, 15) as in :class:`MethodOutput`; ``y`` (B, 15) the
    unknowns ``[α, b, p]`` at the reported point, ``cov_y`` their covariance, ``last_step`` the
    Gauss–Newton step computed there (not applied: below ``tolerance`` σ when converged);
    ``passes`` the number of propagations, ``converged``, ``chi2`` the whitened residual sum
    ``Σ νᵀ S⁻¹ ν`` at the reported point and ``rows`` the number of measurement rows.
    """

    est: np.ndarray
    cov: np.ndarray
    y: np.ndarray
    cov_y: np.ndarray
    last_step: np.ndarray
    passes: np.ndarray
    converged: np.ndarray
    chi2: np.ndarray
    rows: np.ndarray


def solve_batch(
    params: FilterParams,
    data: ScenarioData,
    cov_epochs: np.ndarray,
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = STEP_TOLERANCE,
) -> BatchSolution:
    """Batch least squares on every trial of ``data`` with the noise levels and prior of
    ``params`` (the filter's assumptions; its ``q_p`` is not used: the calibration is constant).

    ``cov_epochs``: epoch indices at which to report the error covariance.
    """
    b, n = data.n_trials, data.n_epochs
    slot = np.full(n, -1, dtype=np.int64)
    slot[np.asarray(cov_epochs, dtype=np.int64)] = np.arange(len(cov_epochs))
    inputs = Inputs(
        gyro=np.ascontiguousarray(data.gyro, dtype=float),
        ads_q=np.ascontiguousarray(data.ads_q, dtype=float),
        ads_rate=np.ascontiguousarray(data.ads_rate, dtype=float),
        meas=kernel_array(data.has_meas, bool, (b, n)),
        slot=slot,
    )
    consts = Constants(
        dt=float(params.dt),
        sigma_a=float(params.sigma_a),
        sigma_r=float(params.sigma_r),
        sigma_v=float(params.sigma_v),
        sigma_u=float(params.sigma_u),
        d=np.ascontiguousarray(params.p0_sigma, dtype=float),
        use_rate=bool(params.use_rate),
        max_iter=int(max_iterations),
        tol=float(tolerance),
    )
    out = Outputs(
        est=np.empty((b, n, 16)),
        cov=np.full((b, len(cov_epochs), 15, 15), np.nan),
        info=np.zeros((b, 4)),
        y=np.empty((b, N_Y)),
        cov_y=np.empty((b, N_Y, N_Y)),
        step=np.empty((b, N_Y)),
    )
    solve_trials(inputs, consts, out)
    return BatchSolution(
        est=out.est,
        cov=out.cov,
        y=out.y,
        cov_y=out.cov_y,
        last_step=out.step,
        passes=out.info[:, 0].astype(np.int64),
        converged=out.info[:, 1] > 0.5,
        chi2=out.info[:, 2],
        rows=out.info[:, 3].astype(np.int64),
    )


def run_batch(cfg: Config, data: ScenarioData) -> MethodOutput:
    """Batch least squares over the whole run (``batch``): constant bias at t = 0 plus its random
    walk, constant calibration, initial attitude (see the package docstring)."""
    sol = solve_batch(FilterParams.from_config(cfg), data, covariance_epochs(cfg))
    diverged = ~np.all(np.isfinite(sol.est), axis=(1, 2))
    alive = ~diverged
    notes = {
        "batch": (
            f"offline: whole-run least squares, constant calibration; "
            f"{np.mean(sol.passes[alive]) if alive.any() else float('nan'):.1f} propagations "
            f"per trial on average, {int(np.sum(~sol.converged & alive))} trial(s) not converged "
            f"in {MAX_ITERATIONS}"
        )
    }
    return MethodOutput(
        est=sol.est,
        diverged=diverged,
        kappa=None,
        logs={
            "passes": sol.passes,
            "converged": sol.converged,
            "chi2": sol.chi2,
            "rows": sol.rows,
        },
        notes=notes,
        cov=sol.cov,
    )
