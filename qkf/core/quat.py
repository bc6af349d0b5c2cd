r"""Compiled SO(3) and quaternion algebra: the numba twin of :mod:`qkf.core.so3`.

One place for the rotation maths of compiled code (the transfer-alignment kernel, the batch
estimator, the truth simulation). Quaternions are scalar-last ``[x, y, z, w]``, as scipy stores
them; ``quat_mul(p, q)`` is the Hamilton product with ``R(p ⊗ q) = R(p) R(q)``, so that
``C ← C Exp(φ)`` reads ``q ← q ⊗ Exp(φ)``. Rotation vectors are in rad.

=========================  ===================================================================
compiled (this module)     numpy (:mod:`qkf.core.so3`)
=========================  ===================================================================
rodrigues_coefficients     rodrigues_coefficients
skew_and_square            skew (and ``skew @ skew``)
exp_and_left_jacobian      exp_matrix, left_jacobian
quat_mul                   quat_mul
quat_from_rotvec           quat_exp
rotvec_from_quat           quat_log
relative_rotvec            quat_log(quat_mul(quat_conj(p), q))
attitude_error_into        —  (rows; numpy-facing: :func:`attitude_error`)
quat_mul_exp               quat_mul(q, quat_exp(φ)), normalised
normalize                  —
cumulative_rotation        —
=========================  ===================================================================

Compile options matter for the bits (:mod:`qkf.core.jit`): the quaternion routines are compiled
without fast-math (strict IEEE arithmetic: the result is the same wherever they are inlined),
the matrix routines with the kernels' :func:`~qkf.core.jit.kernel_jit` options.
``tests/test_so3_core.py`` checks every routine against the numpy one and against
``scipy.spatial.transform.Rotation``.

:func:`attitude_error` (compiled kernel :func:`attitude_error_into`) is the attitude error
``δθ = Log(q̂* ⊗ q)`` of the error metrics, the schedule search and the banks' numpy references.
Compiled per-epoch code, whose quaternions are unit by construction, uses
:func:`relative_rotvec`: the same formula without the normalisation.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from qkf.core.jit import kernel_array, kernel_jit

# ---- Rodrigues coefficients and matrices (kernel options: fast-math, no NRT) -------------------


@kernel_jit()
def rodrigues_coefficients(theta: float) -> tuple[float, float, float]:
    """``a = sin θ/θ``, ``b = (1 − cos θ)/θ²``, ``c = (θ − sin θ)/θ³`` for θ ≥ 0 in rad.

    ``Exp(φ) = I + a [φ×] + b [φ×]²`` and ``J_l(φ) = I + b [φ×] + c [φ×]²`` with ``θ = |φ|``.
    Below 0.1 rad a Taylor series to θ⁸ (truncation < 1e-17 relative): the closed forms lose
    digits to cancellation there. ``b`` in closed form as ``2 sin²(θ/2)/θ²``, which has no
    cancellation.
    """
    t2 = theta * theta
    if theta < 0.1:
        a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0 - t2 * t2 * t2 / 5040.0 + t2**4 / 362880.0
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0 - t2 * t2 * t2 / 40320.0 + t2**4 / 3628800.0
        c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2**3 / 362880.0 + t2**4 / 39916800.0
    else:
        s = np.sin(theta)
        h = np.sin(0.5 * theta)
        a = s / theta
        b = 2.0 * h * h / t2  # (1 − cos θ)/θ² = 2 sin²(θ/2)/θ²
        c = (theta - s) / (t2 * theta)
    return a, b, c


@kernel_jit()
def skew_and_square(w: np.ndarray, out_w: np.ndarray, out_w2: np.ndarray) -> None:
    """``[w×]`` (3×3) into ``out_w`` and its square ``[w×]²`` (the matrix product) into
    ``out_w2``; ``w`` (3,)."""
    out_w[0, 0] = 0.0
    out_w[0, 1] = -w[2]
    out_w[0, 2] = w[1]
    out_w[1, 0] = w[2]
    out_w[1, 1] = 0.0
    out_w[1, 2] = -w[0]
    out_w[2, 0] = -w[1]
    out_w[2, 1] = w[0]
    out_w[2, 2] = 0.0
    for i in range(3):
        for j in range(3):
            v = 0.0
            for k in range(3):
                v += out_w[i, k] * out_w[k, j]
            out_w2[i, j] = v


@kernel_jit()
def _add_skew(m: np.ndarray, s: float, phi: np.ndarray) -> None:
    """``m += s [φ×]`` (3×3) in place, for ``s`` a scalar and ``φ`` (3,)."""
    # [φ×] = [[0, −φz, φy], [φz, 0, −φx], [−φy, φx, 0]]
    m[0, 1] -= s * phi[2]
    m[0, 2] += s * phi[1]
    m[1, 0] += s * phi[2]
    m[1, 2] -= s * phi[0]
    m[2, 0] -= s * phi[1]
    m[2, 1] += s * phi[0]


@kernel_jit()
def exp_and_left_jacobian(phi: np.ndarray, rot: np.ndarray, jac: np.ndarray) -> None:
    """``rot = Exp(φ) = I + a[φ×] + b[φ×]²`` and ``jac = J_l(φ) = I + b[φ×] + c[φ×]²`` (3×3)
    of a rotation vector ``φ`` (3,) in rad, using ``[φ×]² = φφᵀ − θ² I``.

    ``J_l(φ) = ∫₀¹ Exp(τφ) dτ``; the right Jacobian is ``J_r(φ) = J_l(−φ)``.
    """
    theta = np.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    a, b, c = rodrigues_coefficients(theta)
    t2 = theta * theta
    for i in range(3):
        for j in range(3):
            pp = phi[i] * phi[j]
            rot[i, j] = b * pp
            jac[i, j] = c * pp
        rot[i, i] += 1.0 - b * t2
        jac[i, i] += 1.0 - c * t2
    _add_skew(rot, a, phi)  # + a[φ×]
    _add_skew(jac, b, phi)  # + b[φ×]


# ---- quaternions (strict IEEE arithmetic) --------------------------------------------------------
# The scalar forms below are the single definition of each formula; the array routines only load
# and store around them, which keeps them free of scratch arrays (and usable in place).


@nb.njit(cache=True)
def _product(
    px: float, py: float, pz: float, pw: float, qx: float, qy: float, qz: float, qw: float
) -> tuple[float, float, float, float]:
    """Hamilton product ``p ⊗ q`` of scalar-last quaternions given by their components."""
    return (
        pw * qx + qw * px + py * qz - pz * qy,
        pw * qy + qw * py + pz * qx - px * qz,
        pw * qz + qw * pz + px * qy - py * qx,
        pw * qw - px * qx - py * qy - pz * qz,
    )


@nb.njit(cache=True)
def _exp(phi0: float, phi1: float, phi2: float) -> tuple[float, float, float, float]:
    """Quaternion of ``Exp(φ)``: ``[sin(θ/2) φ/θ, cos(θ/2)]``, θ = |φ| (series below 1e-4)."""
    theta = np.sqrt(phi0**2 + phi1**2 + phi2**2)
    if theta < 1e-4:
        t2 = theta * theta
        k = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0  # sin(θ/2)/θ
    else:
        k = np.sin(0.5 * theta) / theta
    return k * phi0, k * phi1, k * phi2, np.cos(0.5 * theta)


@nb.njit(cache=True)
def _log(x: float, y: float, z: float, w: float) -> tuple[float, float, float]:
    """Rotation vector of a unit quaternion: ``2 atan2(|v|, w) v/|v|``, angle in [0, π]."""
    if w < 0.0:  # q and −q are one rotation: take the one with w ≥ 0
        x, y, z, w = -x, -y, -z, -w
    n = np.sqrt(x * x + y * y + z * z)
    k = 2.0 / w if n < 1e-12 else 2.0 * np.arctan2(n, w) / n
    return k * x, k * y, k * z


@nb.njit(cache=True)
def quat_mul(p: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    """Hamilton product ``p ⊗ q`` (scalar-last) into ``out``, so that R(p ⊗ q) = R(p) R(q)."""
    out[0], out[1], out[2], out[3] = _product(p[0], p[1], p[2], p[3], q[0], q[1], q[2], q[3])


@nb.njit(cache=True)
def quat_from_rotvec(phi: np.ndarray, out: np.ndarray) -> None:
    """Quaternion of ``Exp(φ)`` (scalar-last) into ``out``; ``φ`` (3,) in rad."""
    out[0], out[1], out[2], out[3] = _exp(phi[0], phi[1], phi[2])


@nb.njit(cache=True)
def rotvec_from_quat(q: np.ndarray, out: np.ndarray) -> None:
    """``Log`` of a unit quaternion (scalar-last) as a rotation vector (rad) into ``out``, angle
    in [0, π]."""
    out[0], out[1], out[2] = _log(q[0], q[1], q[2], q[3])


@nb.njit(cache=True)
def relative_rotvec(q_from: np.ndarray, q_to: np.ndarray, out: np.ndarray) -> None:
    """``Log(C_fromᵀ C_to)`` (rad) into ``out``: the rotation vector ``δθ`` with
    ``C_to = C_from Exp(δθ)``, from the conjugate product ``q_from* ⊗ q_to``."""
    x, y, z, w = _product(
        -q_from[0], -q_from[1], -q_from[2], q_from[3], q_to[0], q_to[1], q_to[2], q_to[3]
    )
    out[0], out[1], out[2] = _log(x, y, z, w)


@nb.njit(cache=True)
def attitude_error_into(q_hat: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    """Row by row, the attitude error ``δθ = Log(q̂* ⊗ q)`` (rad) of quaternions ``q_hat``,
    ``q`` (M, 4, scalar-last, any length) into ``out`` (M, 3): the rotation vector with
    ``C = Ĉ Exp(δθ)`` (the filter's error convention, docs/models.md), angle in [0, π].

    Both quaternions are scaled to unit length first, as scipy's ``Rotation.from_quat`` does;
    a row where either is not finite (a diverged estimate, a recorded epoch without truth) is
    NaN. The compiled kernel of :func:`attitude_error`; compiled code calls it directly.
    """
    for i in range(q_hat.shape[0]):
        a0, a1, a2, a3 = q_hat[i, 0], q_hat[i, 1], q_hat[i, 2], q_hat[i, 3]
        b0, b1, b2, b3 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        if not (np.isfinite(a0 + a1 + a2 + a3) and np.isfinite(b0 + b1 + b2 + b3)):
            out[i, 0] = out[i, 1] = out[i, 2] = np.nan
            continue
        na = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)
        nb_ = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2 + b3 * b3)
        # q̂* ⊗ q of the unit quaternions
        x, y, z, w = _product(
            -a0 / na, -a1 / na, -a2 / na, a3 / na, b0 / nb_, b1 / nb_, b2 / nb_, b3 / nb_
        )
        out[i, 0], out[i, 1], out[i, 2] = _log(x, y, z, w)


def attitude_error(q_hat: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Attitude error ``δθ = Log(q̂* ⊗ q)`` (…, 3) in rad, i.e. ``C = Ĉ Exp(δθ)``, of scalar-last
    quaternions ``q_hat`` and ``q`` (…, 4) broadcast against each other; any length (both are
    normalised), angle in [0, π], NaN where either is not finite.

    One compiled pass over the rows (:func:`attitude_error_into`): the dozen numpy calls of
    the same formula cost more than its arithmetic at the sizes of an episode step
    (docs/performance.md).
    """
    q_hat, q = np.broadcast_arrays(np.asarray(q_hat, dtype=float), np.asarray(q, dtype=float))
    if q_hat.shape[-1:] != (4,):
        raise ValueError(f"quaternions need a last axis of 4, got shape {q_hat.shape}")
    out = np.empty((*q_hat.shape[:-1], 3))
    attitude_error_into(  # writable C rows: a broadcast view would compile another copy
        kernel_array(q_hat, float, q_hat.shape).reshape(-1, 4),
        kernel_array(q, float, q.shape).reshape(-1, 4),
        out.reshape(-1, 3),
    )
    return out


@nb.njit(cache=True)
def compose_rotvecs(q: np.ndarray, phi: np.ndarray, out: np.ndarray) -> None:
    """Row by row, the quaternion of ``C Exp(φ)`` for quaternions ``q`` (M, 4, any length,
    normalised first) and rotation vectors ``φ`` (M, 3) in rad, into ``out`` (M, 4).

    The operations and their order are those of scipy's
    ``(Rotation.from_quat(q) * Rotation.from_rotvec(φ)).as_quat()`` (Taylor series of
    ``sin(θ/2)/θ`` at θ ≤ 1e-3, the product normalised), so the results agree bit for bit with
    scipy 1.17 (tested) at about a twentieth of its time: the simulator draws every ADS attitude
    this way, and a single environment draws a whole episode at each reset.
    """
    for i in range(q.shape[0]):
        n = np.sqrt(q[i, 0] * q[i, 0] + q[i, 1] * q[i, 1] + q[i, 2] * q[i, 2] + q[i, 3] * q[i, 3])
        p0, p1, p2, p3 = q[i, 0] / n, q[i, 1] / n, q[i, 2] / n, q[i, 3] / n
        angle = np.sqrt(phi[i, 0] * phi[i, 0] + phi[i, 1] * phi[i, 1] + phi[i, 2] * phi[i, 2])
        if angle <= 1e-3:
            a2 = angle * angle
            scale = 0.5 - a2 / 48 + a2 * a2 / 3840  # sin(θ/2)/θ, Taylor
        else:
            scale = np.sin(angle / 2) / angle
        r0, r1, r2, r3 = phi[i, 0] * scale, phi[i, 1] * scale, phi[i, 2] * scale, np.cos(angle / 2)
        # p ⊗ r with the vector part as p₃ r + r₃ p + p × r
        c0, c1, c2 = p1 * r2 - p2 * r1, p2 * r0 - p0 * r2, p0 * r1 - p1 * r0
        o0 = p3 * r0 + r3 * p0 + c0
        o1 = p3 * r1 + r3 * p1 + c1
        o2 = p3 * r2 + r3 * p2 + c2
        o3 = p3 * r3 - p0 * r0 - p1 * r1 - p2 * r2
        m = np.sqrt(o0 * o0 + o1 * o1 + o2 * o2 + o3 * o3)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = o0 / m, o1 / m, o2 / m, o3 / m


@nb.njit(cache=True)
def quat_mul_exp(q: np.ndarray, phi: np.ndarray, out: np.ndarray) -> None:
    """``C_out = C Exp(φ)``: ``q ⊗ Exp(φ)`` normalised to unit length, into ``out`` (which may
    be ``q``); ``φ`` (3,) in rad."""
    ex, ey, ez, ew = _exp(phi[0], phi[1], phi[2])
    x, y, z, w = _product(q[0], q[1], q[2], q[3], ex, ey, ez, ew)
    out[0], out[1], out[2], out[3] = x, y, z, w
    normalize(out)


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
    for k in range(n):
        quat_mul_exp(out[k], rotvecs[k], out[k + 1])
    return out
