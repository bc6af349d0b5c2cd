"""Unit-quaternion algebra for compiled code (scalar-last ``[x, y, z, w]``, as scipy stores them).

``quat_mul(p, q)`` is the Hamilton product with ``R(p ⊗ q) = R(p) R(q)``, so that
``C ← C Exp(φ)`` reads ``q ← q ⊗ quat_from_rotvec(φ)``. Tests check every routine against
``scipy.spatial.transform.Rotation``.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def quat_mul(p: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    """Hamilton product ``p ⊗ q`` (scalar-last), so that R(p ⊗ q) = R(p) R(q)."""
    px, py, pz, pw = p[0], p[1], p[2], p[3]
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    out[0] = pw * qx + qw * px + py * qz - pz * qy
    out[1] = pw * qy + qw * py + pz * qx - px * qz
    out[2] = pw * qz + qw * pz + px * qy - py * qx
    out[3] = pw * qw - px * qx - py * qy - pz * qz


@nb.njit(cache=True)
def quat_from_rotvec(phi: np.ndarray, out: np.ndarray) -> None:
    """Quaternion of ``Exp(φ)`` (scalar-last)."""
    theta = np.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    if theta < 1e-4:
        t2 = theta * theta
        k = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0
    else:
        k = np.sin(0.5 * theta) / theta
    out[0] = k * phi[0]
    out[1] = k * phi[1]
    out[2] = k * phi[2]
    out[3] = np.cos(0.5 * theta)


@nb.njit(cache=True)
def rotvec_from_quat(q: np.ndarray, out: np.ndarray) -> None:
    """``Log`` of a unit quaternion (scalar-last) as a rotation vector, angle in [0, π]."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    n = np.sqrt(x * x + y * y + z * z)
    k = 2.0 / w if n < 1e-12 else 2.0 * np.arctan2(n, w) / n
    out[0] = k * x
    out[1] = k * y
    out[2] = k * z


@nb.njit(cache=True)
def normalize(q: np.ndarray) -> None:
    """Scale a quaternion to unit norm, in place."""
    n = np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    for i in range(4):
        q[i] /= n


@nb.njit(cache=True)
def cumulative_rotation(q0: np.ndarray, rotvecs: np.ndarray) -> np.ndarray:
    """Quaternions (n+1, 4) of ``C_0 = q0``, ``C_{k+1} = C_k Exp(φ_k)``; φ (n, 3) in rad."""
    n = rotvecs.shape[0]
    out = np.empty((n + 1, 4))
    out[0] = q0
    inc = np.empty(4)
    for k in range(n):
        quat_from_rotvec(rotvecs[k], inc)
        quat_mul(out[k], inc, out[k + 1])
        normalize(out[k + 1])
    return out
