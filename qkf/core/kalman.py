r"""Linear Kalman filter primitives, compiled with numba and batched over a leading axis.

Predict::

    x ← Φ x,    P ← Φ P Φᵀ + Q

Update (Joseph form, valid for any gain)::

    ν = z − H x,   S = H P Hᵀ + R,   K = P Hᵀ S⁻¹
    x ← x + K ν,   P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ

The Joseph product is evaluated multiplied out, ``P − K Uᵀ + (K S − U) Kᵀ`` with ``U = P Hᵀ``,
then symmetrised.

``S`` is factored by Cholesky; the update reports the normalised innovation squared
``νᵀ S⁻¹ ν`` and ``log det S`` so that callers can form the innovation log-likelihood
``ℓ = −½ (νᵀ S⁻¹ ν + log det S)``. A non-positive pivot of ``S`` (or a non-finite
input) leaves ``x`` and ``P`` untouched and reports ``ok = False``.

The single-problem routines (``predict_one``, ``update_one``) work on one trial; ``predict``
and ``update`` wrap them for a batch (members in parallel from
:data:`~qkf.core.jit.SERIAL_BELOW` on, else one after the other). The transfer-alignment kernel
(:mod:`qkf.transfer_alignment.kernel`) calls ``update_one`` (with ``make_workspace``) and the
Cholesky helpers (``cholesky_inplace``, ``forward_solve``) for every trial, but not
``predict_one``: its propagation exploits the structure of ``Φ`` (only the attitude rows differ
from the identity's) and adds the correlated-noise terms, so it has its own. The batch
least-squares method (:mod:`qkf.transfer_alignment.methods.batch`) uses the Cholesky helpers
and ``symmetrize_inplace``.
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_array, kernel_jit, row_loops


@kernel_jit(nrt=True)
def cholesky_inplace(s: np.ndarray) -> bool:
    """Lower Cholesky factor of the symmetric matrix ``s``, in place; False if not PD."""
    m = s.shape[0]
    for j in range(m):
        d = s[j, j]
        for k in range(j):
            d -= s[j, k] * s[j, k]
        if not d > 0.0:  # also catches NaN
            return False
        d = np.sqrt(d)
        s[j, j] = d
        for i in range(j + 1, m):
            v = s[i, j]
            for k in range(j):
                v -= s[i, k] * s[j, k]
            s[i, j] = v / d
    for j in range(m):
        for i in range(j):
            s[i, j] = 0.0
    return True


@kernel_jit(nrt=True)
def forward_solve(lower: np.ndarray, b: np.ndarray) -> None:
    """Solve ``L y = b`` in place for a lower-triangular ``L`` (``b`` a vector)."""
    m = lower.shape[0]
    for i in range(m):
        v = b[i]
        for k in range(i):
            v -= lower[i, k] * b[k]
        b[i] = v / lower[i, i]


@kernel_jit(nrt=True)
def backward_solve_t(lower: np.ndarray, b: np.ndarray) -> None:
    """Solve ``Lᵀ y = b`` in place for a lower-triangular ``L`` (``b`` a vector)."""
    m = lower.shape[0]
    for i in range(m - 1, -1, -1):
        v = b[i]
        for k in range(i + 1, m):
            v -= lower[k, i] * b[k]
        b[i] = v / lower[i, i]


@kernel_jit(nrt=True)
def symmetrize_inplace(p: np.ndarray) -> None:
    """``P ← (P + Pᵀ)/2``."""
    n = p.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (p[i, j] + p[j, i])
            p[i, j] = v
            p[j, i] = v


@kernel_jit(nrt=True)
def predict_one(x: np.ndarray, p: np.ndarray, phi: np.ndarray, q: np.ndarray) -> None:
    """Dense predict of one problem, in place."""
    n = x.shape[0]
    xn = phi @ x
    fp = phi @ p
    pn = fp @ phi.T + q
    for i in range(n):
        x[i] = xn[i]
        for j in range(n):
            p[i, j] = pn[i, j]
    symmetrize_inplace(p)


@kernel_jit(nrt=True)
def make_workspace(
    n: int, m: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Scratch arrays for ``update_one`` with n states and m measurements."""
    return (
        np.empty((m, n)),
        np.empty((m, n)),
        np.empty((m, n)),
        np.empty((m, m)),
        np.empty((m, m)),
        np.empty(m),
    )


@kernel_jit(nrt=True, inline=True)
def sparse_rows_times(h: np.ndarray, b: np.ndarray, out: np.ndarray, rows: int, n: int) -> None:
    """``out[:rows, :n] = H[:rows, :n] B[:n, :n]``, skipping the zeros of ``H``: a structured
    measurement matrix costs only its non-zeros. Each row is a sum of rows of ``B`` (axpy
    form: the innermost loop runs along a row and vectorises). Inlined into its caller (numba
    IR), so that constant sizes there give loops of a known trip count."""
    for i in range(rows):
        for j in range(n):
            out[i, j] = 0.0
        for c in range(n):
            hic = h[i, c]
            if hic != 0.0:
                for j in range(n):
                    out[i, j] += hic * b[c, j]


@kernel_jit(nrt=True, inline=True)
def update_sized(
    x: np.ndarray,
    p: np.ndarray,
    nu: np.ndarray,
    h: np.ndarray,
    r: np.ndarray,
    s_out: np.ndarray,
    ws: tuple[np.ndarray, ...],
    n: int,
    m: int,
    gain_innermost: bool,
) -> tuple[bool, float, float]:
    """:func:`update_one` with the sizes ``n`` (states) and ``m`` (measurements) given.

    Inlined into its caller (numba IR), so that a caller passing constants gets loops of a
    known trip count, which LLVM unrolls and vectorises without remainder loops: the
    transfer-alignment kernel passes n = 16 (its 15 states padded by a zero row and column)
    and m = 3 or 6, and its update runs in about two thirds of the time (docs/performance.md).
    ``gain_innermost`` chooses the loop order of the Joseph product: the sum over the gain's
    rows innermost (fastest with constant sizes, where it is fully unrolled) or along a row of
    ``P`` (fastest with sizes known only at run time). Both add the same terms in the same
    order, so they give the same numbers.
    """
    # Loops are written so that the innermost one runs along a row (axpy form): it vectorises
    # and has no dependency chain, which matters more than flop counts at n = 15.
    for i in range(m):
        if not np.isfinite(nu[i]):
            return False, np.nan, np.nan
    ut, kt, g, hph, s, y = ws
    sparse_rows_times(h, p, ut, m, n)  # Uᵀ = H P (P is symmetric: Pᵀ = P)
    if gain_innermost:  # H P Hᵀ from the non-zeros of H only, a short axpy per non-zero
        for i in range(m):
            for j in range(m):
                hph[i, j] = 0.0
            for c in range(n):
                hic = h[i, c]
                if hic != 0.0:
                    for j in range(m):
                        hph[i, j] += hic * ut[j, c]
    else:
        for i in range(m):
            for j in range(m):
                v = 0.0
                for c in range(n):
                    v += h[i, c] * ut[j, c]
                hph[i, j] = v
    for i in range(m):
        for j in range(m):
            s[i, j] = 0.5 * (hph[i, j] + hph[j, i]) + 0.5 * (r[i, j] + r[j, i])
            s_out[i, j] = s[i, j]
    if not cholesky_inplace(s):
        return False, np.nan, np.nan
    logdet = 0.0
    for i in range(m):
        logdet += 2.0 * np.log(s[i, i])
    for i in range(m):
        y[i] = nu[i]
    forward_solve(s, y)
    nis = 0.0
    for i in range(m):
        nis += y[i] * y[i]
    backward_solve_t(s, y)  # y = S⁻¹ ν
    # Kᵀ = S⁻¹ Uᵀ (m×n): forward then backward substitution on whole rows
    for i in range(m):
        for j in range(n):
            kt[i, j] = ut[i, j]
    for i in range(m):
        for c in range(i):
            lic = s[i, c]
            for j in range(n):
                kt[i, j] -= lic * kt[c, j]
        inv = 1.0 / s[i, i]
        for j in range(n):
            kt[i, j] *= inv
    for i in range(m - 1, -1, -1):
        for c in range(i + 1, m):
            lci = s[c, i]
            for j in range(n):
                kt[i, j] -= lci * kt[c, j]
        inv = 1.0 / s[i, i]
        for j in range(n):
            kt[i, j] *= inv
    for c in range(m):
        yc = y[c]
        for i in range(n):
            x[i] += ut[c, i] * yc
    # Joseph form P⁺ = (I − KH) P (I − KH)ᵀ + K R Kᵀ, multiplied out:
    #   P⁺ = P − K Uᵀ + (K (H P Hᵀ + R) − U) Kᵀ,
    # which is the same matrix for any gain K (no optimality of K is used, so an error δK
    # still enters only as δK S δKᵀ). The full square is formed (whole rows vectorise better
    # than triangles at n = 15), then symmetrised.
    for j in range(m):  # gᵀ = (K (R + H P Hᵀ) − U)ᵀ, row by row
        for i in range(n):
            g[j, i] = -ut[j, i]
        for c in range(m):
            coef = r[c, j] + hph[c, j]
            for i in range(n):
                g[j, i] += coef * kt[c, i]
    if gain_innermost:
        for i in range(n):
            for j in range(n):
                acc = p[i, j]
                for c in range(m):
                    acc += g[c, i] * kt[c, j] - kt[c, i] * ut[c, j]
                p[i, j] = acc
    else:
        for i in range(n):
            for c in range(m):
                kic = kt[c, i]
                gic = g[c, i]
                for j in range(n):
                    p[i, j] += gic * kt[c, j] - kic * ut[c, j]
    for i in range(n):  # symmetrize_inplace, with the size known to the caller
        for j in range(i + 1, n):
            v = 0.5 * (p[i, j] + p[j, i])
            p[i, j] = v
            p[j, i] = v
    return True, nis, logdet


@kernel_jit(nrt=True)
def update_one(
    x: np.ndarray,
    p: np.ndarray,
    nu: np.ndarray,
    h: np.ndarray,
    r: np.ndarray,
    s_out: np.ndarray,
    ws: tuple[np.ndarray, ...],
) -> tuple[bool, float, float]:
    """Joseph-form update of one problem with innovation ``ν = z − H x`` (given), in place.

    ``s_out`` (m, m) receives ``S``; ``ws`` is scratch from ``make_workspace(n, m)``.
    Returns ``(ok, νᵀS⁻¹ν, log det S)``. Zeros of ``H`` are skipped, so structured
    measurement matrices cost only their non-zeros.
    """
    return update_sized(x, p, nu, h, r, s_out, ws, x.shape[0], nu.shape[0], False)


@kernel_jit(nrt=True)
def _predict_row(b: int, x: np.ndarray, p: np.ndarray, phi: np.ndarray, q: np.ndarray) -> None:
    """Problem ``b`` of :func:`predict`."""
    predict_one(x[b], p[b], phi[b], q[b])


@kernel_jit(nrt=True)
def _update_row(
    b: int,
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    h: np.ndarray,
    r: np.ndarray,
    ok: np.ndarray,
    nis: np.ndarray,
    logdet: np.ndarray,
) -> None:
    """Problem ``b`` of :func:`update`: ``ν = z − H x``, then :func:`update_one`."""
    nu = z[b] - h[b] @ x[b]
    m = z.shape[1]
    s_out = np.empty((m, m))
    ws = make_workspace(x.shape[1], m)
    ok[b], nis[b], logdet[b] = update_one(x[b], p[b], nu, h[b], r[b], s_out, ws)


_predict_loops = row_loops(_predict_row, "x.shape[0]")
_update_loops = row_loops(_update_row, "x.shape[0]")


def _batched(arr: np.ndarray, batch: int, ndim: int) -> np.ndarray:
    """``arr`` (its last ``ndim`` axes) for every batch member: one writable C array type
    (:func:`~qkf.core.jit.kernel_array`; a broadcast view compiled the update again)."""
    arr = np.asarray(arr, dtype=np.float64)
    return kernel_array(arr, np.float64, (batch, *arr.shape[arr.ndim - ndim :]))


def predict(x: np.ndarray, p: np.ndarray, phi: np.ndarray, q: np.ndarray) -> None:
    """Batched dense predict, in place: ``x`` (B, n) and ``P`` (B, n, n) float64 C-contiguous.

    ``phi`` and ``q`` are (n, n) or (B, n, n).
    """
    _check_state(x, p)
    b = x.shape[0]
    _predict_loops.for_rows(b)(x, p, _batched(phi, b, 2), _batched(q, b, 2))


def update(
    x: np.ndarray, p: np.ndarray, z: np.ndarray, h: np.ndarray, r: np.ndarray
) -> dict[str, np.ndarray]:
    """Batched Joseph-form update, in place: ``z`` (B, m); ``h``, ``r`` unbatched or batched.

    Returns ``ok``, ``nis`` (νᵀS⁻¹ν) and ``logdet_s`` per batch member.
    """
    _check_state(x, p)
    b = x.shape[0]
    z = _batched(z, b, 1)
    ok = np.zeros(b, dtype=np.bool_)
    nis = np.empty(b)
    logdet = np.empty(b)
    _update_loops.for_rows(b)(x, p, z, _batched(h, b, 2), _batched(r, b, 2), ok, nis, logdet)
    return {"ok": ok, "nis": nis, "logdet_s": logdet}


def _check_state(x: np.ndarray, p: np.ndarray) -> None:
    for name, arr, nd in (("x", x, 2), ("P", p, 3)):
        if arr.dtype != np.float64 or arr.ndim != nd or not arr.flags.c_contiguous:
            raise ValueError(f"{name} must be a C-contiguous float64 array with {nd} axes")
    if p.shape != (x.shape[0], x.shape[1], x.shape[1]):
        raise ValueError(f"P shape {p.shape} does not match x shape {x.shape}")
