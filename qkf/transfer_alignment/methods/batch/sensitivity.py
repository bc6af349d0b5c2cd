r"""Gyro-propagated attitude and its sensitivity to the unknowns ``y = [α, b, p]`` (compiled).

With ``ω̂_k = A (ω̃_k − b)``, ``A = (I + K(p))⁻¹`` and ``Ĉ_{k+1} = Ĉ_k Exp(ω̂_k Δt)``, a change
``dy`` of the unknowns moves the attitude as ``Ĉ_k(y + dy) ≈ Ĉ_k(y) Exp(S_k dy)`` with::

    Ĉ_0 = C_start Exp(α),   S_0 = [J_r(α), 0, 0]
    S_{k+1} = R_k S_k + Γ_k ∂ω̂_k/∂y,   ∂ω̂/∂y = [0, −A, −A Ω(ω̂)]
    R_k = Exp(−ω̂_k Δt),   Γ_k = Δt J_l(−ω̂_k Δt)

(``J_r(α) = J_l(−α)``). The rotation algebra is :mod:`qkf.core.quat`'s, the model pieces
(``A``, ``ω̂``, ``∂ω̂/∂y``) are :mod:`qkf.transfer_alignment.model_compiled`'s.
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit
from qkf.core.quat import exp_and_left_jacobian, quat_mul_exp
from qkf.transfer_alignment.methods.batch.dense import mm_add
from qkf.transfer_alignment.model_compiled import rate_estimate, rate_jacobian

N_Y = 15
"""Unknowns per trial: α (3), b (3), p (9)."""


@kernel_jit(nrt=True)
def initial_attitude(
    q_start: np.ndarray,
    y: np.ndarray,
    phi: np.ndarray,
    rot: np.ndarray,
    jac: np.ndarray,
    s: np.ndarray,
    q0: np.ndarray,
) -> None:
    """``Ĉ_0 = C_start Exp(α)`` into ``q0`` and ``S_0 = [J_r(α), 0, 0]`` into the first three
    columns of ``s`` (3×15; the others are left as they are); ``phi``, ``rot``, ``jac`` are
    scratch."""
    for i in range(3):
        phi[i] = -y[i]
    exp_and_left_jacobian(phi, rot, jac)  # J_r(α) = J_l(−α)
    for i in range(3):
        for j in range(3):
            s[i, j] = jac[i, j]
    quat_mul_exp(q_start, y[0:3], q0)


@kernel_jit(nrt=True)
def step_sensitivity(
    s: np.ndarray, rot: np.ndarray, jac: np.ndarray, g: np.ndarray, dt: float
) -> None:
    """``S ← R S + Γ ∂ω̂/∂y`` in place (``rot`` = R, ``g`` = ∂ω̂/∂y (3×15), ``Γ = Δt jac``)."""
    tmp = np.zeros(s.shape)
    mm_add(rot, s, tmp)
    gam = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            gam[i, j] = dt * jac[i, j]
    mm_add(gam, g, tmp)
    s[:] = tmp


@kernel_jit(nrt=True)
def step_attitude(
    q_k: np.ndarray,
    w: np.ndarray,
    g: np.ndarray,
    dt: float,
    s: np.ndarray,
    phi: np.ndarray,
    rot: np.ndarray,
    jac: np.ndarray,
    q_next: np.ndarray,
) -> None:
    """One step ``k → k+1`` at the rate ``ω̂_k`` (``w``, rad/s): ``S`` in place (``g`` =
    ∂ω̂_k/∂y) and ``Ĉ_{k+1} = Ĉ_k Exp(ω̂_k Δt)`` into ``q_next``; ``phi``, ``rot``, ``jac``
    are scratch."""
    for i in range(3):
        phi[i] = -w[i] * dt
    exp_and_left_jacobian(phi, rot, jac)  # R = Exp(−ω̂Δt), Γ = Δt J_l(−ω̂Δt)
    step_sensitivity(s, rot, jac, g, dt)
    for i in range(3):
        phi[i] = w[i] * dt
    quat_mul_exp(q_k, phi, q_next)


@kernel_jit(nrt=True)
def propagate_sensitivity(
    gyro: np.ndarray, q_start: np.ndarray, y: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro-propagated attitude of one trial and its sensitivity to ``y = [α, b, p]`` (SI).

    ``gyro`` (N, 3) rad/s, ``q_start`` the attitude ``Ĉ_0`` is taken relative to (scalar-last),
    ``dt`` s. Returns quaternions ``q`` (N, 4) of ``Ĉ_k``, rates ``ω̂`` (N, 3) and ``S`` (N, 3, 15)
    with ``Ĉ_k(y + dy) ≈ Ĉ_k(y) Exp(S_k dy)``; all NaN if ``I + K(p)`` is singular.
    """
    n = gyro.shape[0]
    q = np.empty((n, 4))
    w = np.empty((n, 3))
    sens = np.empty((n, 3, N_Y))
    a = np.empty((3, 3))
    rot = np.empty((3, 3))
    jac = np.empty((3, 3))
    s = np.zeros((3, N_Y))
    g = np.empty((3, N_Y))
    phi = np.empty(3)
    initial_attitude(q_start, y, phi, rot, jac, s, q[0])
    for k in range(n):
        # ω̂_k = A (ω̃_k − b),  A = (I + K(p))⁻¹
        if not rate_estimate(gyro[k], y[3:6], y[6:15], a, w[k]):
            q[:] = np.nan
            w[:] = np.nan
            sens[:] = np.nan
            return q, w, sens
        sens[k] = s
        if k == n - 1:
            break
        rate_jacobian(a, w[k], g)  # ∂ω̂/∂y = [0, −A, −A Ω(ω̂)]
        step_attitude(q[k], w[k], g, dt, s, phi, rot, jac, q[k + 1])
    return q, w, sens
