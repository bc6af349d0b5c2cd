r"""The compiled calibration UKF: one epoch, a span of one episode, and decision periods of a
batch of episodes (docs/redundant_gyros.md, "The compiled UKF").

The filter of :class:`~qkf.redundant_gyros.ukf.CalibrationUKF` (filterpy's UKF with Merwe
sigma points and an identity process model), written once as :func:`ukf_step`:

    P⁻ = P + κ Δt diag(q²)                                   (random-walk prediction)
    χ = [x, x ± columns of chol((λ + n) P⁻)]                   (2n + 1 sigma points)
    ẑ = Σ Wm h(χ),  S = R(x) + Σ Wc (h(χ) − ẑ)²,  P_xz = Σ Wc (χ − x)(h(χ) − ẑ)
    K = P_xz / S,  x ← x + K (z − ẑ),  P ← P⁻ − K S Kᵀ, symmetrised

with ``h`` and ``R(x)`` (at the predicted state) of :mod:`~qkf.redundant_gyros.ukf`. A failed
Cholesky, ``S ≤ 0`` or a non-finite value is a failure (the caller stops the filter). filterpy
stays the reference: the estimates agree to 1e-9 σ₀ over whole episodes with κ changing
(``tests/test_gyro_ukf_compiled.py``), at about a thousandth of the cost.

Compiled without the kernels' fast-math flags (``fastmath=False`` of
:func:`qkf.core.jit.kernel_jit`): strict IEEE arithmetic, as numpy (and filterpy) computes.

Its users: :func:`run_span` (the hindsight search, :mod:`qkf.redundant_gyros.hindsight`) and
:func:`run_periods` (the environments, :mod:`envs.redundant_gyros.episodes`), which steps every
episode of a batch over its next decision period in parallel over episodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.core.jit import kernel_jit, row_loops
from qkf.redundant_gyros.ukf import DIM, UkfSetup

Geometry = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, np.ndarray]
"""``(w, u, v, G_H⁻¹, s_H, σ_j, q²)``: the unit's geometry and noise, as the filter reads them."""
Work = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""The scratch of :func:`ukf_step` (:func:`step_work`)."""


@dataclass(frozen=True)
class CompiledSetup:
    """The constants of the compiled filter of one :class:`UkfSetup`.

    ``geometry = (w, u, v, G_H⁻¹, s_H, σ_j, q²)``; ``weights = [λ + n, Wm0, Wc0, Wi]`` of the
    Merwe points.
    """

    geometry: Geometry
    weights: np.ndarray

    @classmethod
    def of(cls, s: UkfSetup) -> CompiledSetup:
        n = DIM
        lam = s.alpha**2 * (n + s.kappa_points) - n
        wm0 = lam / (n + lam)
        weights = np.array([n + lam, wm0, wm0 + 1.0 - s.alpha**2 + s.beta, 0.5 / (n + lam)])
        geometry = (s.w, s.u, s.v, s.triad_inv, s.triad_noise, float(s.noise), s.q_sd**2)
        return cls(geometry, weights)


@kernel_jit(nrt=True, fastmath=False)
def _cholesky(a: np.ndarray, out: np.ndarray) -> bool:  # pragma: no cover - compiled
    """Lower Cholesky factor of the 4 × 4 ``a`` into ``out``; False if not positive definite."""
    n = a.shape[0]
    for j in range(n):
        s = a[j, j]
        for m in range(j):
            s -= out[j, m] * out[j, m]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        out[j, j] = d
        for i in range(j + 1, n):
            s = a[i, j]
            for m in range(j):
                s -= out[i, m] * out[j, m]
            out[i, j] = s / d
        for i in range(j):
            out[i, j] = 0.0
    return True


@kernel_jit(nrt=True, fastmath=False)
def _h(
    s: np.ndarray, w: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray
) -> float:  # pragma: no cover
    """``(1 − λ) (w − δ_u u − δ_v v)ᵀ ω̂ − b`` of state ``s``, deg/s."""
    acc = 0.0
    for m in range(3):
        acc += (w[m] - s[2] * u[m] - s[3] * v[m]) * r[m]
    return (1.0 - s[1]) * acc - s[0]


@kernel_jit(nrt=True, fastmath=False)
def noise_variance(s: np.ndarray, geometry: Geometry) -> float:  # pragma: no cover - compiled
    """``R(x) = σ² + ‖(1 − λ) w̄(x)ᵀ G_H⁻¹ diag(s_H)‖²`` of state ``s``, (deg/s)², with the
    unit's ``geometry`` (:attr:`CompiledSetup.geometry`)."""
    w, u, v, tinv, tnoise, noise, _ = geometry
    rr = noise * noise
    for m in range(3):
        acc = 0.0
        for m2 in range(3):
            acc += (1.0 - s[1]) * (w[m2] - s[2] * u[m2] - s[3] * v[m2]) * tinv[m2, m]
        acc *= tnoise[m]
        rr += acc * acc
    return rr


@kernel_jit(nrt=True, fastmath=False)
def step_work() -> Work:
    """Work arrays of :func:`ukf_step`: chol, scaled, sigma points, h(χ), P_xz."""
    n = DIM
    return (
        np.zeros((n, n)),
        np.zeros((n, n)),
        np.zeros((2 * n + 1, n)),
        np.zeros(2 * n + 1),
        np.zeros(n),
    )


@kernel_jit(nrt=True, fastmath=False)
def ukf_step(
    x: np.ndarray,
    p: np.ndarray,
    z: float,
    r: np.ndarray,
    dt: float,
    kap: float,
    geometry: Geometry,
    weights: np.ndarray,
    work: Work,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """One predict + update of ``(x, p)`` in place with reading ``z`` and triad rate ``r``
    (deg/s), step ``dt`` (s) and factor ``kap`` (module docstring), the unit's ``geometry`` and
    the Merwe ``weights`` (:class:`CompiledSetup`). Returns the innovation ``ν`` and its
    variance ``S``; ``S`` is NaN if the filter failed (``x``, ``p`` undefined)."""
    w, u, v, _, _, _, q2 = geometry
    chol, scaled, sig, hs, pxz = work
    n = 4
    lam_n, wm0, wc0, wi = weights[0], weights[1], weights[2], weights[3]
    for i in range(n):
        p[i, i] += kap * dt * q2[i]
    for i in range(n):
        for j in range(n):
            scaled[i, j] = lam_n * p[i, j]
    if not _cholesky(scaled, chol):
        return np.nan, np.nan
    for i in range(n):
        sig[0, i] = x[i]
    for c in range(n):
        for i in range(n):
            sig[1 + c, i] = x[i] + chol[i, c]
            sig[1 + n + c, i] = x[i] - chol[i, c]
    zp = 0.0
    for j in range(2 * n + 1):
        hs[j] = _h(sig[j], w, u, v, r)
        zp += (wm0 if j == 0 else wi) * hs[j]
    s = noise_variance(x, geometry)  # R at the predicted state
    for i in range(n):
        pxz[i] = 0.0
    for j in range(2 * n + 1):
        wc = wc0 if j == 0 else wi
        dz = hs[j] - zp
        s += wc * dz * dz
        for i in range(n):
            pxz[i] += wc * (sig[j, i] - x[i]) * dz
    if not (s > 0.0 and np.isfinite(s)):
        return np.nan, np.nan
    y = z - zp
    for i in range(n):
        x[i] += pxz[i] / s * y
    for i in range(n):
        for j in range(n):
            p[i, j] -= (pxz[i] / s) * s * (pxz[j] / s)
    for i in range(n):
        for j in range(i + 1, n):
            m_ij = 0.5 * (p[i, j] + p[j, i])
            p[i, j] = m_ij
            p[j, i] = m_ij
    for i in range(n):
        if not np.isfinite(x[i]):
            return y, np.nan
        for j in range(n):
            if not np.isfinite(p[i, j]):
                return y, np.nan
    return y, s


@kernel_jit(nrt=True, fastmath=False)
def run_span(
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    rate: np.ndarray,
    dt: np.ndarray,
    kappa: np.ndarray,
    truth: np.ndarray,
    inv_sd: np.ndarray,
    k0: int,
    k1: int,
    settled_from: int,
    geometry: Geometry,
    weights: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """Run the UKF (``x`` (4,), ``p`` (4, 4), in place) over epochs ``[k0, k1)`` of one
    episode with ``kappa[k − k0]``; return the sum of the squared normalised errors
    ``((x̂ − x) inv_sd)²`` over the epochs from ``settled_from`` on, NaN if the filter fails."""
    work = step_work()
    total = 0.0
    for k in range(k0, k1):
        _, s = ukf_step(x, p, z[k], rate[k], dt[k], kappa[k - k0], geometry, weights, work)
        if np.isnan(s):
            return np.nan
        if k >= settled_from:
            for i in range(4):
                e = (x[i] - truth[k, i]) * inv_sd[i]
                total += e * e
    return total


SUMS = ("nis", "loglik", "loglik_nominal", "error", "error_sq", "lag1")
"""The per-period sums :func:`run_periods` returns per episode, in this order: ``Σ ν²/S``,
``Σ ℓ`` and the κ = 1 copy's ``Σ ℓ`` with ``ℓ = −½ (ν²/S + log S)``, ``Σ ‖(x̂ − x) / σ₀‖``,
``Σ ‖(x̂ − x) / σ₀‖²`` and ``Σ_{i ≥ 1} r_i r_{i−1}`` with ``r = ν/√S`` the normalised
innovations of the period (their lag-1 products: about 0 when the filter's process noise is
right whatever the white noise, positive when the coefficients move faster than it assumes)."""


@kernel_jit(nrt=True, fastmath=False)
def _period_row(
    b: int,
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    rate: np.ndarray,
    dt: np.ndarray,
    truth: np.ndarray,
    inv_sd: np.ndarray,
    kappa: np.ndarray,
    k0: np.ndarray,
    k1: np.ndarray,
    nominal: bool,
    keep_cov: bool,
    w: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    tinv: np.ndarray,
    tnoise: np.ndarray,
    noise: float,
    q2: np.ndarray,
    weights: np.ndarray,
    failed: np.ndarray,
    nominal_failed: np.ndarray,
    sums: np.ndarray,
    err: np.ndarray,
    cov: np.ndarray,
    est: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Step episode ``b`` of a batch over its epochs ``[k0[b], k1[b])`` with ``kappa[b]``;
    ``x`` (B, 4), ``p`` (B, 4, 4) and ``failed`` (B,) in place. A failed episode is not stepped.

    Inputs per episode: ``z`` (B, K), ``rate`` (B, K, 3), ``truth`` (B, K, 4); shared:
    ``dt`` (K,), ``inv_sd`` (4,) = 1/σ₀. Outputs: ``sums`` (B, 6), the :data:`SUMS` over the
    epochs run; ``err`` (B, P, 4) ``x̂ − x`` per epoch of the period and, if ``keep_cov``,
    ``cov`` (B, P, 4, 4) the updated covariance and ``est`` (B, P, 4) the estimate ``x̂``, NaN
    where not run (past ``k1 − k0``, from a failure on). With
    ``nominal`` a κ = 1 copy of each episode runs from the period's start over the same
    epochs (for ``sums[:, 2]``; ``nominal_failed`` if it fails, the agent's filter not). The
    geometry ``w`` … ``q2`` and the ``weights`` are those of :class:`CompiledSetup`."""
    geometry = (w, u, v, tinv, tnoise, noise, q2)
    work = step_work()
    xs = x[b].copy()  # the state at the period's start, for the κ = 1 copy
    ps = p[b].copy()
    err[b] = np.nan
    if keep_cov:
        cov[b] = np.nan
        est[b] = np.nan
    for j in range(sums.shape[1]):
        sums[b, j] = 0.0
    nominal_failed[b] = False
    steps = k1[b] - k0[b]
    if failed[b]:
        return
    r_prev = 0.0
    for i in range(steps):
        k = k0[b] + i
        y, s = ukf_step(x[b], p[b], z[b, k], rate[b, k], dt[k], kappa[b], geometry, weights, work)
        if np.isnan(s):
            failed[b] = True
            return
        sums[b, 0] += y * y / s
        sums[b, 1] += -0.5 * (y * y / s + np.log(s))
        r = y / np.sqrt(s)
        if i > 0:
            sums[b, 5] += r * r_prev
        r_prev = r
        norm2 = 0.0
        for j in range(4):
            e = x[b, j] - truth[b, k, j]
            err[b, i, j] = e
            norm2 += (e * inv_sd[j]) ** 2
        sums[b, 3] += np.sqrt(norm2)
        sums[b, 4] += norm2
        if keep_cov:
            for j in range(4):
                est[b, i, j] = x[b, j]
                for m in range(4):
                    cov[b, i, j, m] = p[b, j, m]
    if not nominal:
        return
    for i in range(steps):
        k = k0[b] + i
        y, s = ukf_step(xs, ps, z[b, k], rate[b, k], dt[k], 1.0, geometry, weights, work)
        if np.isnan(s):
            nominal_failed[b] = True
            return
        sums[b, 2] += -0.5 * (y * y / s + np.log(s))


run_periods = row_loops(_period_row, "x.shape[0]", fastmath=False).parallel
""":func:`_period_row` for every episode of a batch (its arguments after the episode index),
episodes in parallel."""


__all__ = [
    "SUMS",
    "CompiledSetup",
    "noise_variance",
    "run_periods",
    "run_span",
    "step_work",
    "ukf_step",
]
