r"""The transfer-alignment error model, compiled (numba): the pieces that compiled code and the
methods share, the twin of the numpy reference :mod:`qkf.transfer_alignment.model`.

Calibration vector and rate (docs/models.md)::

    p = [s_x, s_y, s_z, k_xy, k_xz, k_yz, k_yx, k_zx, k_zy]
    K(p) = [[s_x, k_xy, k_xz], [k_yx, s_y, k_yz], [k_zx, k_zy, s_z]],    K(p) ω = Ω(ω) p
    A = (I + K(p̂))⁻¹,   ω̂ = A (ω̃ − b̂)                                    (rate_estimate)

Transition over a step ``Δt`` with ``ω̂`` held (rows of the attitude error; the bias and
calibration rows of ``Φ`` are those of the identity)::

    Φ_top = [R, −Γ A, −Γ A Ω(ω̂)],   R(s) = Exp(−ω̂ s),   Γ(s) = s J_l(−ω̂ s)
                                    (attitude_transition, a_omega, phi_top_rows)

Measurement: the attitude residual ``z_a = Log(Ĉᵀ C_ADS)`` (:func:`attitude_residual`) and the
rate rows ``H_r = [0, −A, −A Ω(ω̂)]`` (:func:`rate_jacobian`).

Used by the filter kernel (:mod:`qkf.transfer_alignment.kernel`), by the batch estimator
(:mod:`qkf.transfer_alignment.methods.batch`) and, through the batched wrappers at the end
(:func:`transition_matrix`, :func:`attitude_innovation`), by the methods that need the filter's
own ``Φ`` or attitude innovation (fading, vbakf). Every routine is compiled with the kernel's
options (:func:`qkf.core.jit.kernel_jit`), so the filter computes the same bits whichever module
holds it; ``tests/test_model_compiled.py`` checks each against the numpy model.

Units SI: rad, rad/s, s; ``p`` dimensionless.
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit
from qkf.core.quat import relative_rotvec, rodrigues_coefficients, skew_and_square

# Column l of Ω(ω) has one non-zero, ω[OM_COL[l]], in row OM_ROW[l] (docs/models.md):
#          s_x s_y s_z k_xy k_xz k_yz k_yx k_zx k_zy
OM_ROW = np.array([0, 1, 2, 0, 0, 1, 1, 2, 2])
OM_COL = np.array([0, 1, 2, 1, 2, 2, 0, 0, 1])


@kernel_jit()
def rate_estimate(
    gyro: np.ndarray, b_hat: np.ndarray, p_hat: np.ndarray, a: np.ndarray, w: np.ndarray
) -> bool:
    """``A = (I + K(p̂))⁻¹`` (3×3) into ``a`` by the adjugate and ``ω̂ = A (ω̃ − b̂)`` (rad/s)
    into ``w``; ``gyro`` = ω̃, ``b_hat`` = b̂ (rad/s). False (``a``, ``w`` untouched) if
    ``I + K`` is singular (``|det| ≤ 1e-12``) or not finite.

    The filter kernel's routine as it was, statement for statement (its arithmetic, hence its
    bits, are those of the filter). Callers that need ``A`` alone pass ``ω̃ = b̂`` and ignore
    ``ω̂``.
    """
    # M = I + K(p̂), entries named m_rc
    m00, m11, m22 = 1.0 + p_hat[0], 1.0 + p_hat[1], 1.0 + p_hat[2]
    m01, m02, m12 = p_hat[3], p_hat[4], p_hat[5]
    m10, m20, m21 = p_hat[6], p_hat[7], p_hat[8]
    # cofactors of the first row: det M = Σ_j m_0j c_0j
    c00 = m11 * m22 - m12 * m21
    c01 = m12 * m20 - m10 * m22
    c02 = m10 * m21 - m11 * m20
    det = m00 * c00 + m01 * c01 + m02 * c02
    if not (abs(det) > 1e-12 and np.isfinite(det)):
        return False
    inv = 1.0 / det
    # A = adj(M) / det M,  adj(M)_ij = cofactor_ji
    a[0, 0] = c00 * inv
    a[1, 0] = c01 * inv
    a[2, 0] = c02 * inv
    a[0, 1] = (m02 * m21 - m01 * m22) * inv
    a[1, 1] = (m00 * m22 - m02 * m20) * inv
    a[2, 1] = (m01 * m20 - m00 * m21) * inv
    a[0, 2] = (m01 * m12 - m02 * m11) * inv
    a[1, 2] = (m02 * m10 - m00 * m12) * inv
    a[2, 2] = (m00 * m11 - m01 * m10) * inv
    # ω̂ = A u,  u = ω̃ − b̂
    u0 = gyro[0] - b_hat[0]
    u1 = gyro[1] - b_hat[1]
    u2 = gyro[2] - b_hat[2]
    for i in range(3):
        w[i] = a[i, 0] * u0 + a[i, 1] * u1 + a[i, 2] * u2
    return True


@kernel_jit()
def a_omega(a: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """``A Ω(ω)`` (3×9) into ``out``: column l is ``ω[OM_COL[l]]`` times column ``OM_ROW[l]``
    of ``A``."""
    for l in range(9):
        col = OM_ROW[l]
        v = w[OM_COL[l]]
        for i in range(3):
            out[i, l] = a[i, col] * v


@kernel_jit()
def rate_jacobian(a: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """``[0, −A, −A Ω(ω)]`` (3×15) into ``out``: the derivative of ``ω̂ = A (ω̃ − b)`` with
    respect to the error state ``[δθ, Δb, Δp]`` (``H_r`` of rate matching, before scaling)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.0
            out[i, 3 + j] = -a[i, j]
        for l in range(9):
            out[i, 6 + l] = -a[i, OM_ROW[l]] * w[OM_COL[l]]


@kernel_jit()
def attitude_transition(
    wx: np.ndarray, wx2: np.ndarray, rate: float, s: float, r: np.ndarray, g: np.ndarray
) -> None:
    """``R = Exp(−ω̂ s)`` and ``Γ = s · J_l(−ω̂ s) = ∫₀ˢ Exp(−ω̂ u) du`` (3×3) into ``r``, ``g``.

    ``wx`` = [−ω̂×] and ``wx2`` = [−ω̂×]² (:func:`qkf.core.quat.skew_and_square`) are computed
    once per step by the caller, so the quadrature nodes of ``Q_d`` reuse them; ``rate`` = |ω̂|
    in rad/s, ``s`` in s. With φ = −ω̂ s: [φ×] = s·wx and [φ×]² = s²·wx2.
    """
    a, b, c = rodrigues_coefficients(rate * s)
    a1 = a * s
    b2 = b * s * s
    b1 = b * s
    c2 = c * s * s
    for i in range(3):
        for j in range(3):
            e = 1.0 if i == j else 0.0
            r[i, j] = e + a1 * wx[i, j] + b2 * wx2[i, j]
            g[i, j] = s * (e + b1 * wx[i, j] + c2 * wx2[i, j])


@kernel_jit(inline=True)
def phi_top_rows(
    rr: np.ndarray,
    gg: np.ndarray,
    a: np.ndarray,
    aom: np.ndarray,
    ratio: np.ndarray,
    phi_top: np.ndarray,
) -> None:
    """Rows 0..2 of ``Φ̃ = D⁻¹ Φ D`` into ``phi_top`` (3×15; the other rows of Φ are those of
    the identity)::

        Φ_top = [R, −Γ A, −Γ A Ω(ω̂)],   R = Exp(−ω̂ Δt),  Γ = Δt J_l(−ω̂ Δt)

    ``rr`` = R, ``gg`` = Γ (:func:`attitude_transition`), ``aom`` = A Ω(ω̂) (:func:`a_omega`),
    ``ratio`` = d_j / d_i (the kernel's state scales; all ones for Φ itself, in SI).
    """
    for i in range(3):
        for j in range(3):
            # Φ̃_θθ = R d_θj / d_θi
            phi_top[i, j] = rr[i, j] * ratio[i, j]
            # Φ̃_θb = −(Γ A) d_bj / d_θi
            v = 0.0
            for c in range(3):
                v += gg[i, c] * a[c, j]
            phi_top[i, 3 + j] = -v * ratio[i, 3 + j]
        for l in range(9):
            # Φ̃_θp = −(Γ A Ω) d_pl / d_θi
            v = 0.0
            for c in range(3):
                v += gg[i, c] * aom[c, l]
            phi_top[i, 6 + l] = -v * ratio[i, 6 + l]


@kernel_jit()
def attitude_residual(q_hat: np.ndarray, ads_q: np.ndarray, out: np.ndarray) -> None:
    """Attitude measurement ``z_a = Log(Ĉᵀ C_ADS)`` (rad) into ``out``, quaternions
    scalar-last: the attitude error ``δθ`` of ``C_ADS = Ĉ Exp(δθ)`` plus the ADS noise."""
    relative_rotvec(q_hat, ads_q, out)


# ---- batched wrappers for numpy callers ----------------------------------------------------------


@kernel_jit(nrt=True)
def _transition_rows(rate: np.ndarray, p_hat: np.ndarray, dt: float, out: np.ndarray) -> None:
    """Φ (n, 15, 15) over ``dt`` for rates (n, 3) and calibrations (n, 9); NaN if singular."""
    a = np.empty((3, 3))
    aom = np.empty((3, 9))
    neg_w = np.empty(3)
    wx = np.empty((3, 3))
    wx2 = np.empty((3, 3))
    rr = np.empty((3, 3))
    gg = np.empty((3, 3))
    ones = np.ones((3, 15))  # SI: no state scaling
    zero = np.zeros(3)
    unused = np.empty(3)
    for n in range(rate.shape[0]):
        phi = out[n]
        phi[:] = 0.0
        for i in range(15):
            phi[i, i] = 1.0
        if not rate_estimate(zero, zero, p_hat[n], a, unused):  # A alone
            phi[0:3, :] = np.nan
            continue
        w = rate[n]
        a_omega(a, w, aom)
        for i in range(3):
            neg_w[i] = -w[i]
        skew_and_square(neg_w, wx, wx2)  # [−ω̂×], [−ω̂×]²
        norm = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        attitude_transition(wx, wx2, norm, dt, rr, gg)
        phi_top_rows(rr, gg, a, aom, ones, phi[0:3, :])


def transition_matrix(rate: np.ndarray, p_hat: np.ndarray, dt: float) -> np.ndarray:
    """The filter's exact ``Φ`` (…, 15, 15) over ``dt`` (s) at rates ``ω̂`` (…, 3, rad/s) and
    ``A = (I + K(p̂))⁻¹`` of ``p̂`` (…, 9): ``[[R, −Γ A, −Γ A Ω(ω̂)], [0, I, 0], [0, 0, I]]``.

    The arithmetic of the kernel's propagation, in SI (the kernel holds ``D⁻¹ Φ D``). Rows whose
    ``I + K(p̂)`` is singular get NaN in the attitude rows.
    """
    rate = np.asarray(rate, dtype=float)
    lead = rate.shape[:-1]
    flat_rate = np.ascontiguousarray(rate.reshape(-1, 3))
    flat_p = np.ascontiguousarray(np.broadcast_to(p_hat, (*lead, 9)).reshape(-1, 9), dtype=float)
    out = np.empty((flat_rate.shape[0], 15, 15))
    _transition_rows(flat_rate, flat_p, float(dt), out)
    return out.reshape(*lead, 15, 15)


@kernel_jit(nrt=True)
def _residual_rows(q_hat: np.ndarray, ads_q: np.ndarray, out: np.ndarray) -> None:
    """``Log(Ĉᵀ C_ADS)`` (n, 3) of quaternion pairs (n, 4)."""
    for n in range(q_hat.shape[0]):
        attitude_residual(q_hat[n], ads_q[n], out[n])


def attitude_innovation(q_hat: np.ndarray, ads_q: np.ndarray) -> np.ndarray:
    """``z_a = Log(Ĉᵀ C_ADS)`` (…, 3) in rad of scalar-last quaternions (…, 4): the filter's
    attitude innovation, bit for bit, as the kernel forms it at ``Ĉ = q_hat``."""
    q_hat = np.asarray(q_hat, dtype=float)
    lead = np.broadcast_shapes(q_hat.shape, np.shape(ads_q))[:-1]
    flat_q = np.ascontiguousarray(np.broadcast_to(q_hat, (*lead, 4)).reshape(-1, 4))
    flat_ads = np.ascontiguousarray(np.broadcast_to(ads_q, (*lead, 4)).reshape(-1, 4), dtype=float)
    out = np.empty((flat_q.shape[0], 3))
    _residual_rows(flat_q, flat_ads, out)
    return out.reshape(*lead, 3)
