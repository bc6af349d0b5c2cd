"""The numpy reference of the VBAKF's measurement update (qkf/transfer_alignment/methods/vbakf.py),
for the tests.

The method runs compiled (:mod:`qkf.transfer_alignment.methods.vbakf_compiled`); :func:`vb_step`
is the same variational-Bayes update in numpy for any state size, and
:func:`scaled_measurement` the filter's measurement model in the method's scaled units. The
tests check the compiled step and epoch against them (to 1e-12), and ``vb_step(...,
compiled=True)`` runs the compiled step behind the same interface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.core.jit import kernel_jit, row_loops
from qkf.transfer_alignment import model
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.methods.vbakf import row_scales
from qkf.transfer_alignment.methods.vbakf_compiled import vb_iterate
from qkf.transfer_alignment.model_compiled import attitude_innovation


@kernel_jit()
def _vb_row(
    b: int,
    p_nom: np.ndarray,
    nu: np.ndarray,
    h: np.ndarray,
    r_nom: np.ndarray,
    u_prev: np.ndarray,
    us_prev: np.ndarray,
    tau: float,
    rho: float,
    iterations: int,
    adapt_p: bool,
    adapt_r: bool,
    isotropic: bool,
    dx: np.ndarray,
    p: np.ndarray,
    p_hat: np.ndarray,
    r: np.ndarray,
    u: np.ndarray,
    us: np.ndarray,
    ws: np.ndarray,
) -> None:
    """Row ``b`` of :func:`vb_rows`: ``vb_iterate`` with the posterior, shapes as there with
    the batch in front (``h`` (B, m, 15)); ``ws`` (B, 7, max(m, a + 1), max(m, 15)) is scratch.
    A row whose Cholesky factor of ``S`` fails gets NaN in every output."""
    ok, u_new = vb_iterate(
        p_nom[b], nu[b], h[b], r_nom[b], u_prev[b], us_prev[b], tau, rho, iterations,
        adapt_p, adapt_r, isotropic, True, dx[b], p[b], p_hat[b], r[b], us[b], ws[b],
    )  # fmt: skip
    u[b] = u_new
    if not ok:
        dx[b] = np.nan
        p[b] = np.nan
        p_hat[b] = np.nan
        r[b] = np.nan
        us[b] = np.nan
        u[b] = np.nan


vb_rows = row_loops(_vb_row, "h.shape[0]").serial
""":func:`_vb_row` for every row of a batch (its arguments after the row index), rows one
after the other (the serial loop compiles in a third of the parallel one's time); the
outputs ``dx`` … ``us`` are written in place. The caller checks the shapes. The method
itself calls ``vb_iterate`` from its epoch routine; this loop is the tests' door to the step
alone."""


@dataclass(frozen=True)
class VbStep:
    """Result of one VB measurement update (:func:`vb_step`), batch on axis 0."""

    x: np.ndarray  # (B, n) x̂⁺ = x̂⁽ᴺ⁾
    p: np.ndarray  # (B, n, n) P⁺ = P⁽ᴺ⁾
    u: np.ndarray  # (B,) û_k, dof of the R posterior
    u_scale: np.ndarray  # (B, a, a) Û_k, its inverse scale matrix
    p_pred: np.ndarray  # (B, n, n) P̂⁻ of the last iteration
    r: np.ndarray  # (B, m, m) R̂ of the last iteration (adapted block + the fixed rest)


def _sym(m: np.ndarray) -> np.ndarray:
    return 0.5 * (m + np.swapaxes(m, -1, -2))


def vb_step(
    x_pred: np.ndarray,
    p_nom: np.ndarray,
    z: np.ndarray,
    h: np.ndarray,
    r_nominal: np.ndarray,
    u_prev: np.ndarray,
    u_scale_prev: np.ndarray,
    *,
    tau: float,
    rho: float,
    iterations: int,
    adapt_p: bool = True,
    adapt_r: bool = True,
    isotropic: bool = False,
    compiled: bool = False,
) -> VbStep:
    """One VBAKF measurement update (module docstring), batched over axis 0.

    ``x_pred`` (B, n) x̂⁻; ``p_nom`` (B, n, n) the nominal prediction P̃⁻; ``z`` (B, m);
    ``h`` (B, m, n); ``r_nominal`` (B, m, m): R as assumed. The leading ``a × a`` block of R is
    adapted, where ``a`` is the size of ``u_scale_prev`` (B, a, a); the rest of ``r_nominal``
    is used as given (and its cross terms with the adapted block). ``u_prev`` (B,) and
    ``u_scale_prev`` are the R posterior of the previous measurement (:func:`r_prior` at the
    start). ``isotropic``: update with ``(tr R̂_a / a) I`` instead of ``R̂_a``.

    ``compiled``: the compiled step
    (:data:`vb_rows`) instead of numpy, for the 15 error states only: the same results to
    rounding, rows independent of each other, and a row whose ``S`` has a non-positive
    Cholesky pivot (or NaN) gets NaN everywhere.
    """
    if iterations < 1:
        raise ValueError("iterations must be at least 1")
    if compiled:
        inputs = (x_pred, p_nom, z, h, r_nominal, u_prev, u_scale_prev)
        return _vb_step_compiled(inputs, (tau, rho, iterations, adapt_p, adapt_r, isotropic))
    x_pred = np.asarray(x_pred, dtype=float)
    p_nom = np.asarray(p_nom, dtype=float)
    z = np.asarray(z, dtype=float)
    h = np.asarray(h, dtype=float)
    r_nominal = np.asarray(r_nominal, dtype=float)
    n = p_nom.shape[-1]
    a = np.shape(u_scale_prev)[-1]
    ht = np.swapaxes(h, -1, -2)
    eye_n = np.eye(n)
    u_pred = (
        rho * (np.asarray(u_prev, dtype=float) - a - 1.0) + a + 1.0
    )  # û⁻ = ρ(û − m − 1) + m + 1
    u_scale_pred = rho * np.asarray(u_scale_prev, dtype=float)  # Û⁻ = ρ Û
    t_scale_pred = tau * p_nom  # T̂⁻ = τ P̃⁻  (t̂⁻ = n + τ + 1)
    innov = z - np.einsum("...ij,...j->...i", h, x_pred)  # z − H x̂⁻
    x, p = x_pred, p_nom  # x̂⁽⁰⁾ = x̂⁻, P⁽⁰⁾ = P̃⁻
    u, u_scale = u_pred, u_scale_pred
    p_hat, r = p_nom, r_nominal
    for _ in range(iterations):
        if adapt_p:
            dx = x - x_pred
            a_mat = dx[..., :, None] * dx[..., None, :] + p  # A = (x̂ − x̂⁻)(x̂ − x̂⁻)ᵀ + P
            # P̂⁻ = T̂/(t̂ − n − 1) with t̂ = n + τ + 2, T̂ = τ P̃⁻ + A
            p_hat = _sym(t_scale_pred + a_mat) / (tau + 1.0)
        if adapt_r:
            res = (z - np.einsum("...ij,...j->...i", h, x))[..., :a]  # z − H x̂
            hph = h[..., :a, :] @ p @ ht[..., :, :a]  # (H P Hᵀ) of the adapted rows
            b_mat = res[..., :, None] * res[..., None, :] + _sym(hph)  # B = (z − Hx̂)(…)ᵀ + HPHᵀ
            u = u_pred + 1.0  # û = û⁻ + 1
            u_scale = u_scale_pred + b_mat  # Û = Û⁻ + B
            r_a = u_scale / (u - a - 1.0)[..., None, None]  # R̂ = Û/(û − m − 1)
            if isotropic:
                tr = np.trace(r_a, axis1=-2, axis2=-1) / a
                r_a = tr[..., None, None] * np.eye(a)
            r = r_nominal.copy()
            r[..., :a, :a] = r_a
        s = _sym(h @ p_hat @ ht + r)  # S = H P̂⁻ Hᵀ + R̂
        kt = np.linalg.solve(s, h @ p_hat)  # Kᵀ = S⁻¹ H P̂⁻
        k = np.swapaxes(kt, -1, -2)
        x = x_pred + np.einsum("...ij,...j->...i", k, innov)  # x̂ = x̂⁻ + K (z − H x̂⁻)
        ikh = eye_n - k @ h
        p = _sym(ikh @ p_hat @ np.swapaxes(ikh, -1, -2) + k @ r @ kt)  # Joseph form
    return VbStep(x=x, p=p, u=u, u_scale=u_scale, p_pred=p_hat, r=r)


def _vb_step_compiled(
    inputs: tuple[np.ndarray, ...], settings: tuple[float, float, int, bool, bool, bool]
) -> VbStep:
    """:func:`vb_step` with ``compiled``: ``inputs`` its arrays in its order (``x_pred`` …
    ``u_scale_prev``), ``settings`` = (τ, ρ, N, adapt_p, adapt_r, isotropic)."""
    x_pred, p_nom, z, h, r_nominal, u_prev, u_scale_prev = inputs
    tau, rho, iterations, adapt_p, adapt_r, isotropic = settings
    n = model.N_STATES
    if np.shape(h)[-1] != n or np.shape(p_nom)[-2:] != (n, n):
        raise ValueError(f"the compiled VB step is for {n} states, H is {np.shape(h)}")
    x_pred = np.asarray(x_pred, dtype=float)
    p_nom = np.ascontiguousarray(p_nom, dtype=float)
    h = np.ascontiguousarray(h, dtype=float)
    r_nominal = np.ascontiguousarray(r_nominal, dtype=float)
    b, m, n = h.shape
    a = np.shape(u_scale_prev)[-1]
    nu = np.ascontiguousarray(np.asarray(z, dtype=float) - np.einsum("bij,bj->bi", h, x_pred))
    dx, u = np.empty((b, n)), np.empty(b)
    p, p_hat = np.empty((b, n, n)), np.empty((b, n, n))
    r, u_scale = np.empty((b, m, m)), np.empty((b, a, a))
    ws = np.empty((b, 7, max(m, a + 1), max(m, n)))  # the scratch of vb_iterate, per row
    vb_rows(
        p_nom, nu, h, r_nominal,
        np.ascontiguousarray(u_prev, dtype=float), np.ascontiguousarray(u_scale_prev, dtype=float),
        float(tau), float(rho), int(iterations), bool(adapt_p), bool(adapt_r), bool(isotropic),
        dx, p, p_hat, r, u, u_scale, ws,
    )  # fmt: skip
    return VbStep(x=x_pred + dx, p=p, u=u, u_scale=u_scale, p_pred=p_hat, r=r)


def scaled_measurement(
    kf: TransferAlignmentKF, gyro: np.ndarray, ads_q: np.ndarray, ads_rate: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The filter's measurement model at its current estimate, in its scaled units.

    Returns ``(ν̃, H̃, R̃, e)``: ``ν̃ = E⁻¹ν`` (B, m), ``H̃ = E⁻¹ H D`` (B, m, 15),
    ``R̃ = E⁻¹ R E⁻¹`` (B, m, m) with the *nominal* attitude sigma, and the row scales ``e``
    (m,): ``e_a = σ_a`` (assumed), ``e_r = √(σ_r² + σ_v²/Δt)``. ``gyro``, ``ads_q``,
    ``ads_rate`` are epoch k's samples (B, 3 / 4 / 3).
    """
    prm = kf.params
    # diverged trials may hold NaN or a singular I + K(p̂): compute them on the initial estimate
    live = ~kf.diverged & np.isfinite(kf.b_hat).all(axis=1) & np.isfinite(kf.p_hat).all(axis=1)
    b_hat = np.where(live[:, None], kf.b_hat, 0.0)
    p_hat = np.where(live[:, None], kf.p_hat, 0.0)
    a, w_hat = model.rate_estimate(gyro, b_hat, p_hat)  # A = (I + K(p̂))⁻¹, ω̂ = A (ω̃ − b̂)
    h, r = model.measurement_model(
        w_hat, a, prm.dt, prm.sigma_a, prm.sigma_r, prm.sigma_v, prm.use_rate
    )
    nu = attitude_innovation(kf.q_hat, ads_q)  # z_a = Log(Ĉᵀ C_ADS)
    e = row_scales(prm)
    if prm.use_rate:
        nu = np.concatenate([nu, ads_rate - w_hat], axis=-1)  # z_r = ω_ADS − ω̂
    d = prm.p0_sigma
    return nu / e, h * d / e[:, None], r / np.outer(e, e), e
