"""Rotation algebra on numpy arrays, batched over leading axes: the one numpy rotation core.

The skew matrix, the coefficient functions of the Rodrigues formula and of the SO(3) Jacobian,
``Exp`` as a matrix, the left Jacobian, and unit-quaternion algebra (product, conjugate, ``Exp``
and ``Log``). Quaternions are scalar-last ``[x, y, z, w]``, as ``scipy.spatial.transform.Rotation``
stores them, and ``quat_mul(p, q)`` is the Hamilton product with ``R(p ⊗ q) = R(p) R(q)``, so
``C ← C Exp(φ)`` reads ``q ← quat_mul(q, quat_exp(φ))``. Rotation vectors are in rad.

:mod:`qkf.core.quat` is the compiled (numba) twin of these routines, for compiled code;
``tests/test_so3_core.py`` checks the two against each other and against scipy.
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v×]`` of vectors with a last axis of 3; returns ``(..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def rodrigues_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``a = sin θ/θ``, ``b = (1 − cos θ)/θ²``, ``c = (θ − sin θ)/θ³``, accurate down to θ = 0.

    ``Exp(φ) = I + a [φ×] + b [φ×]²`` and the left Jacobian
    ``J(φ) = ∫₀¹ Exp(τφ) dτ = I + b [φ×] + c [φ×]²``, with ``θ = |φ|`` in rad.
    """
    theta = np.asarray(theta, dtype=float)
    a = np.sinc(theta / np.pi)
    b = 0.5 * np.sinc(theta / (2.0 * np.pi)) ** 2
    t2 = theta * theta
    small = theta < 0.1
    # Series below 0.1 rad: the closed form loses digits to cancellation there.
    series = 1.0 / 6.0 - t2 / 120.0 + t2**2 / 5040.0 - t2**3 / 362880.0 + t2**4 / 39916800.0
    safe = np.where(small, 1.0, theta)
    closed = (safe - np.sin(safe)) / safe**3
    c = np.where(small, series, closed)
    return a, b, c


def exp_matrix(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix ``Exp(φ) = I + a [φ×] + b [φ×]²`` of rotation vectors ``φ`` (rad),
    shape ``(..., 3, 3)``."""
    return _skew_series(phi, 0)


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian ``J(φ) = ∫₀¹ Exp(τφ) dτ = I + b [φ×] + c [φ×]²``, shape
    ``(..., 3, 3)``; ``φ`` in rad."""
    return _skew_series(phi, 1)


def _skew_series(phi: np.ndarray, first: int) -> np.ndarray:
    """``I + k₀ [φ×] + k₁ [φ×]²`` with ``(k₀, k₁)`` two consecutive Rodrigues coefficients of
    ``θ = |φ|``, from ``first`` on in ``(a, b, c)``: 0 gives ``Exp(φ)``, 1 gives ``J(φ)``."""
    phi = np.asarray(phi, dtype=float)
    coeffs = rodrigues_coefficients(np.linalg.norm(phi, axis=-1))
    k0, k1 = coeffs[first], coeffs[first + 1]
    w = skew(phi)
    eye = np.broadcast_to(np.eye(3), w.shape)
    return eye + k0[..., None, None] * w + k1[..., None, None] * (w @ w)


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p ⊗ q`` of scalar-last quaternions (…, 4): ``R(p ⊗ q) = R(p) R(q)``."""
    px, py, pz, pw = np.moveaxis(p, -1, 0)
    qx, qy, qz, qw = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qx + qw * px + py * qz - pz * qy,
            pw * qy + qw * py + pz * qx - px * qz,
            pw * qz + qw * pz + px * qy - py * qx,
            pw * qw - px * qx - py * qy - pz * qz,
        ],
        axis=-1,
    )


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate of scalar-last quaternions (…, 4): the inverse rotation of a unit quaternion."""
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_exp(phi: np.ndarray) -> np.ndarray:
    """Unit quaternions (…, 4), scalar-last, of ``Exp(φ)`` for rotation vectors (…, 3) in rad:
    ``[sin(θ/2) φ/θ, cos(θ/2)]`` with θ = |φ|."""
    theta = np.linalg.norm(phi, axis=-1)
    t2 = theta * theta
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    # sin(θ/2)/θ: its Taylor series below 1e-4 rad, where the quotient would lose digits
    k = np.where(small, 0.5 - t2 / 48.0 + t2 * t2 / 3840.0, np.sin(0.5 * safe) / safe)
    return np.concatenate([k[..., None] * phi, np.cos(0.5 * theta)[..., None]], axis=-1)


def quat_log(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (…, 3) in rad, angle in [0, π], of unit quaternions (…, 4), scalar-last:
    ``2 atan2(|v|, w) v/|v|`` after choosing the sign with ``w ≥ 0`` (q and −q are one
    rotation)."""
    q = np.where(q[..., 3:4] < 0.0, -q, q)
    v, w = q[..., :3], q[..., 3]
    n = np.linalg.norm(v, axis=-1)
    small = n < 1e-12
    k = np.where(
        small, 2.0 / np.where(small, w, 1.0), 2.0 * np.arctan2(n, w) / np.where(small, 1.0, n)
    )
    return k[..., None] * v
