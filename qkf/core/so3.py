"""Rotation helpers on numpy arrays, batched over leading axes.

Quaternions and conversions go through ``scipy.spatial.transform.Rotation`` (scalar-last);
what is here is the small-angle-safe algebra that scipy does not expose: the skew matrix and
the coefficient functions of the Rodrigues formula and of the SO(3) Jacobian.
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
    """Rotation matrix ``Exp(φ)`` of rotation vectors ``φ`` (rad), shape ``(..., 3, 3)``."""
    phi = np.asarray(phi, dtype=float)
    a, b, _ = rodrigues_coefficients(np.linalg.norm(phi, axis=-1))
    w = skew(phi)
    eye = np.broadcast_to(np.eye(3), w.shape)
    return eye + a[..., None, None] * w + b[..., None, None] * (w @ w)


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian ``J(φ) = ∫₀¹ Exp(τφ) dτ``, shape ``(..., 3, 3)``."""
    phi = np.asarray(phi, dtype=float)
    _, b, c = rodrigues_coefficients(np.linalg.norm(phi, axis=-1))
    w = skew(phi)
    eye = np.broadcast_to(np.eye(3), w.shape)
    return eye + b[..., None, None] * w + c[..., None, None] * (w @ w)
