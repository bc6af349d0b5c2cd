r"""Rates and angular accelerations from a quaternion series (docs/sca_fusion.md,
"Angular acceleration from quaternions").

For ``q̇ = ½ q ⊗ (ω, 0)`` (body rate, scalar-last)::

    ω = 2 vec(q* ⊗ q̇),      ω̇ = 2 vec(q* ⊗ q̈)      (q̇* ⊗ q̇ = |q̇|² has no vector part)

The derivatives of q at epoch i come from the polynomial of degree d through d + 1 neighbouring
epochs — the window centred on i, shifted inside the arc at its ends — so the weights
``w_k`` (``q^{(ν)}(t_i) ≈ Σ_k w_k q_{s_i + k}``) are exact for polynomials up to degree d:
d = 2 gives ``[1, −2, 1]/Δt²``, d = 4 ``[−1, 16, −30, 16, −1]/(12 Δt²)``.
"""

from __future__ import annotations

from functools import lru_cache
from math import factorial

import numpy as np

# The quaternion algebra is the core's; re-exported under these names for the arc modules.
from qkf.core.so3 import quat_conj as quat_conj
from qkf.core.so3 import quat_exp as quat_exp
from qkf.core.so3 import quat_log as quat_log
from qkf.core.so3 import quat_mul as quat_mul


def sign_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions (n, 4) lie on one hemisphere (q and −q are one
    rotation; differences need a continuous series)."""
    if q.shape[0] < 2:
        return q.copy()
    flip = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0.0
    sign = np.concatenate([[1.0], np.where(np.cumsum(flip) % 2 == 1, -1.0, 1.0)])
    return q * sign[:, None]


@lru_cache(maxsize=64)
def _offset_weights(degree: int, order: int, offset: int) -> tuple[float, ...]:
    """Weights on nodes ``0 … d`` (unit spacing) for the ``order``-th derivative at node
    ``offset``: the solution of ``Σ_k w_k (k − offset)^j = d^order/dτ^order τ^j |_0``."""
    nodes = np.arange(degree + 1, dtype=float) - offset
    vander = np.vander(nodes, degree + 1, increasing=True).T  # row j: nodes^j
    target = np.zeros(degree + 1)
    target[order] = float(factorial(order))
    return tuple(np.linalg.solve(vander, target))


def derivative_weights(
    n_epochs: int, degree: int, order: int, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Window start ``s`` (n,) and weights ``w`` (n, d + 1) with
    ``f^{(order)}(t_i) ≈ Σ_k w[i, k] f(t_{s_i + k})`` on a uniform grid of step ``dt`` (s);
    exact for polynomials up to ``degree``. Needs ``n_epochs > degree``."""
    if n_epochs <= degree:
        raise ValueError(f"{n_epochs} epochs: at least {degree + 1} needed for degree {degree}")
    if not 0 < order <= degree:
        raise ValueError(f"derivative order {order} for degree {degree}")
    i = np.arange(n_epochs)
    start = np.clip(i - degree // 2, 0, n_epochs - degree - 1)
    offsets = i - start
    table = np.array([_offset_weights(degree, order, k) for k in range(degree + 1)])
    return start, table[offsets] / dt**order


def windowed_sum(q: np.ndarray, start: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``Σ_k w[i, k] q[s_i + k]`` for every epoch (n, 4)."""
    idx = start[:, None] + np.arange(weights.shape[1])[None, :]
    return np.einsum("ik,ikj->ij", weights, q[idx])


def body_rate(q: np.ndarray, dt: float, degree: int = 2) -> np.ndarray:
    """Body-frame rate ``ω = 2 vec(q* ⊗ q̇)`` (rad/s) of a sign-continuous series (n, 4)."""
    start, w = derivative_weights(q.shape[0], degree, 1, dt)
    return 2.0 * quat_mul(quat_conj(q), windowed_sum(q, start, w))[:, :3]


def angular_acceleration(q: np.ndarray, dt: float, degree: int = 2) -> np.ndarray:
    """Body-frame angular acceleration ``ω̇ = 2 vec(q* ⊗ q̈)`` (rad/s²) of a sign-continuous
    series (n, 4), q̈ from the degree-d polynomial weights."""
    start, w = derivative_weights(q.shape[0], degree, 2, dt)
    return 2.0 * quat_mul(quat_conj(q), windowed_sum(q, start, w))[:, :3]


def euler_term(omega: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """Gyroscopic term ``I⁻¹ (ω × I ω)`` (rad/s²) for a diagonal inertia ``I`` (3,): what a
    non-cubic proof mass adds to the measured angular acceleration (Euler's equations)."""
    inertia = np.asarray(inertia, dtype=float)
    return np.cross(omega, omega * inertia) / inertia
