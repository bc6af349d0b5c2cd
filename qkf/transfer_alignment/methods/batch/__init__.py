r"""Batch least-squares gyro calibration (``batch``): the offline counterpart of the filter
(docs/methods.md, "Batch least squares").

Unknowns, one set per trial and constant over the run::

    y = [α (3), b (3), p (9)]      Ĉ_0 = C_ADS,0 Exp(α),   b: gyro bias at t = 0,   p: calibration

Given ``y`` the gyro is integrated over the whole run, ``ω̂_k = A (ω̃_k − b)``,
``A = (I + K(p))⁻¹``, ``Ĉ_{k+1} = Ĉ_k Exp(ω̂_k Δt)``. The residuals are the attitude difference
``z_a,k = Log(Ĉ_kᵀ C_ADS,k)`` and (with rate matching) ``z_r,k = ω_ADS,k − ω̂_k``. Their Jacobian
with respect to ``y`` follows from the sensitivity of the propagated attitude,
``Ĉ_k(y + dy) = Ĉ_k(y) Exp(S_k dy)``, propagated along the trajectory::

    S_0 = [J_r(α), 0, 0],   S_{k+1} = R_k S_k + [0, −Γ_k A, −Γ_k A Ω(ω̂_k)]
    R_k = Exp(−ω̂_k Δt),     Γ_k = Δt J_r(ω̂_k Δt)
    z_a,k ≈ S_k dy + ξ_k + ν_a,k
    z_r,k ≈ [0, −A, −A Ω(ω̂_k)] dy − A β_k − A η_k + ν_r,k

The gyro's angle and rate random walks make the residuals coloured: the attitude carries the
integrated gyro noise ``ξ``, the bias drifts by ``β`` from its value at t = 0, and the gyro noise
``η_k`` of the rate residual is the one that drives ``ξ`` over the next step::

    ξ_{k+1} = R_k ξ_k − Γ_k A β_k − Γ_k A η_k,    β_{k+1} = β_k + u_k,    ξ_0 = β_0 = 0

Weighting the residuals as white would count that noise twice (the estimate stays unbiased but
is far from the bound, and its covariance is wrong). The normal equations are therefore formed
from residuals whitened by a Kalman filter over the six nuisance states ``n = [ξ, β]`` (with the
correlated-noise prediction of the transfer-alignment filter), run on the residual column and
the fifteen Jacobian columns at once: with innovations ``ν_k`` and their covariance ``S_k``,

    N = P_y0⁻¹ + Σ_k ν_{H,k}ᵀ S_k⁻¹ ν_{H,k},   n = Σ_k ν_{H,k}ᵀ S_k⁻¹ ν_{z,k} − P_y0⁻¹ y

which is generalised least squares with the exact covariance of the stacked residuals. The
prior ``P_y0 = diag(filter.initial_sigma²)`` enters as a pseudo-observation. Gauss–Newton:
``y ← y + N⁻¹ n``, re-propagate, repeat until every component of the step is below
:data:`STEP_TOLERANCE` times its standard deviation (usually three passes).

Reported per epoch: ``p̂`` (constant), ``b̂_k = b̂ + β̂_k`` and ``Ĉ_k Exp(ξ̂_k)`` with the
nuisance smoothed over the whole run (modified Bryson–Frazier backward pass). Covariance at the
sampled epochs: ``M_k P_y M_kᵀ + P^n_{k|N}`` (the smoothing error is orthogonal to all
innovations, hence to the error of ``ŷ``), ``M_k`` mapping ``dy`` to the error state through
``S_k`` and the smoothed Jacobian columns.

Everything runs per trial in one compiled kernel (trials in parallel), in units scaled by the
prior sigmas (``y``) and by the measurement sigmas (rows and nuisance states). One module per
concern:

- :mod:`.sensitivity`: gyro-propagated attitude and its sensitivity ``S_k``;
- :mod:`.forward`: one pass at ``y``: residual and Jacobian columns, the nuisance filter, the
  normal equations;
- :mod:`.smoother`: the smoothing pass, the reported estimates and covariances;
- :mod:`.solver`: the Gauss–Newton iteration per trial, trials in parallel;
- :mod:`.method`: the driver (:func:`solve_batch`) and the method (:func:`run_batch`);
- :mod:`.structs`, :mod:`.dense`: the named groups of arrays and constants, small dense
  products.

The rotation algebra is the compiled core's (:mod:`qkf.core.quat`), ``A``, ``ω̂``, ``∂ω̂/∂y`` and
the attitude residual the compiled model's (:mod:`qkf.transfer_alignment.model_compiled`).
"""

from qkf.transfer_alignment.methods.batch.method import (
    MAX_ITERATIONS,
    STEP_TOLERANCE,
    BatchSolution,
    run_batch,
    solve_batch,
)
from qkf.transfer_alignment.methods.batch.sensitivity import propagate_sensitivity

__all__ = [
    "MAX_ITERATIONS",
    "STEP_TOLERANCE",
    "BatchSolution",
    "propagate_sensitivity",
    "run_batch",
    "solve_batch",
]
