r"""Cholesky solve and selected inverse of a banded normal matrix with a dense border
(docs/least_squares.md, "Banded solve with a border").

The parameters are ordered ``[band | border]``::

    N = [[B,  C],        B (n_b × n_b): banded, half bandwidth p (N_jk = 0 for |j − k| > p)
         [Cᵀ, D]]        C (n_b × g), D (g × g): the g global parameters, dense

Solve (Schur complement onto the border; B is never inverted densely)::

    B = L Lᵀ                 banded Cholesky, O(n_b p²)
    Z = B⁻¹ C                g banded solves
    S = D − Cᵀ Z             Schur complement (g × g), dense Cholesky
    x_g = S⁻¹ (n_g − Zᵀ n_b)
    x_b = B⁻¹ (n_b − C x_g)

Selected inverse: the entries of N⁻¹ on the band (and the whole border) from the same factor::

    N⁻¹ = [[B⁻¹ + W Zᵀ,  −W],      W = Z S⁻¹
           [−Wᵀ,         S⁻¹]]

The band of ``B⁻¹`` comes from the Takahashi recursion on ``L`` (``Σ L = L⁻ᵀ`` read column by
column from the last one), O(n_b q p) for a band of half width q ≥ p. Every entry of N⁻¹ that a
quadratic form ``aᵀ N⁻¹ a`` needs, for a design row ``a`` that contributed to N, lies on that
pattern, which is what the redundancy numbers of :mod:`qkf.core.least_squares` use.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

import qkf.core.jit  # noqa: F401  (binds compiled callees locally: docs/performance.md)


class NotPositiveDefiniteError(np.linalg.LinAlgError):
    """The normal matrix is singular or indefinite: some parameters are not determined."""


def half_bandwidth(matrix: sp.spmatrix | sp.sparray, n_band: int) -> int:
    """Half bandwidth ``max |j − k|`` over the structural non-zeros of the leading
    ``n_band × n_band`` block of a sparse matrix (0 for a diagonal block)."""
    coo = sp.coo_matrix(matrix)
    inside = (coo.row < n_band) & (coo.col < n_band)
    if not inside.any():
        return 0
    return int(np.max(np.abs(coo.row[inside].astype(np.int64) - coo.col[inside])))


def lower_band_storage(matrix: sp.spmatrix | sp.sparray, n_band: int, p: int) -> np.ndarray:
    """The lower band of the leading block as LAPACK stores it: ``ab[k, j] = M[j + k, j]``,
    shape ``(p + 1, n_band)`` (``scipy.linalg.cholesky_banded(ab, lower=True)`` takes it)."""
    mat = sp.csr_matrix(matrix)
    ab = np.zeros((p + 1, n_band))
    for k in range(min(p, n_band - 1) + 1):
        ab[k, : n_band - k] = mat.diagonal(-k)[: n_band - k]  # the band block leads
    return ab


@nb.njit(cache=True)
def takahashi_band(lower: np.ndarray, q: int) -> np.ndarray:
    """Band of ``(L Lᵀ)⁻¹`` of half width ``q`` from the banded lower Cholesky factor.

    ``lower[k, j] = L[j + k, j]`` (k = 0 … p). Returns ``sig[k, j] = Σ[j + k, j]`` for
    k = 0 … q (q ≥ p; entries past the end are zero). From ``Σ L = L⁻ᵀ``, for j ≥ i::

        Σ[j, i] = (δ_ji / L_ii − Σ_{m=i+1}^{i+p} L[m, i] Σ[j, m]) / L_ii

    evaluated for i = n − 1 … 0, off-diagonal entries (j > i) before the diagonal one.
    """
    p = lower.shape[0] - 1
    n = lower.shape[1]
    sig = np.zeros((q + 1, n))
    for i in range(n - 1, -1, -1):
        lii = lower[0, i]
        mmax = min(p, n - 1 - i)
        for k in range(min(q, n - 1 - i), 0, -1):
            j = i + k
            acc = 0.0
            for m in range(1, mmax + 1):
                r = i + m  # Σ[j, r] with both j, r in (i, i + q]
                if j >= r:
                    acc += lower[m, i] * sig[j - r, r]
                else:
                    acc += lower[m, i] * sig[r - j, j]
            sig[k, i] = -acc / lii
        acc = 0.0
        for m in range(1, mmax + 1):
            acc += lower[m, i] * sig[m, i]
        sig[0, i] = (1.0 / lii - acc) / lii
    return sig


@nb.njit(cache=True)
def _row_quadratic_forms(
    indptr: np.ndarray,
    indices: np.ndarray,
    data: np.ndarray,
    n_band: int,
    band: np.ndarray,
    w: np.ndarray,
    s_inv: np.ndarray,
) -> tuple[np.ndarray, bool]:
    """``a_iᵀ N⁻¹ a_i`` over the non-zeros of each CSR row; False if a pair of band columns
    lies outside the band held in ``band`` (lower storage)."""
    q = band.shape[0] - 1
    m = indptr.size - 1
    out = np.zeros(m)
    complete = True
    for i in range(m):
        acc = 0.0
        for a in range(indptr[i], indptr[i + 1]):
            j = indices[a]
            va = data[a]
            for b in range(indptr[i], indptr[i + 1]):
                k = indices[b]
                vb = data[b]
                if j < n_band and k < n_band:
                    lo = min(j, k)
                    d = max(j, k) - lo
                    if d > q:
                        complete = False
                    else:
                        acc += va * vb * band[d, lo]
                elif j < n_band:
                    acc -= va * vb * w[j, k - n_band]  # (N⁻¹)_bg = −W
                elif k < n_band:
                    acc -= va * vb * w[k, j - n_band]
                else:
                    acc += va * vb * s_inv[j - n_band, k - n_band]
        out[i] = acc
    return out, complete


class BandedBorderedCholesky:
    """Factor of a symmetric positive-definite ``N = [[B, C], [Cᵀ, D]]`` with banded ``B``.

    ``normal``: the sparse (or dense) symmetric matrix, parameters ordered ``[band | border]``;
    ``n_band``: how many leading parameters form the band (0: all border, a dense Cholesky);
    ``bandwidth``: half bandwidth of ``B`` (default: read from the non-zero structure).
    Raises :class:`NotPositiveDefiniteError` when N is not positive definite.
    """

    def __init__(
        self,
        normal: sp.spmatrix | sp.sparray | np.ndarray,
        n_band: int,
        bandwidth: int | None = None,
    ) -> None:
        n = normal.shape[0]
        if normal.shape != (n, n) or not 0 <= n_band <= n:
            raise ValueError(f"normal matrix {normal.shape} with n_band = {n_band}")
        mat = sp.csr_matrix(normal)
        self._band_cache: dict[int, sp.csr_matrix] = {}
        self._band_cache_raw: dict[int, np.ndarray] = {}
        self.n_band = n_band
        self.n_border = n - n_band
        self.bandwidth = half_bandwidth(mat, n_band) if bandwidth is None else int(bandwidth)
        nb_, g = n_band, self.n_border
        if nb_:
            ab = lower_band_storage(mat, nb_, self.bandwidth)
            try:
                self._lower = sla.cholesky_banded(ab, lower=True, check_finite=True)
            except (np.linalg.LinAlgError, ValueError) as exc:
                raise NotPositiveDefiniteError(f"banded block: {exc}") from None
            self._c = mat[:nb_, nb_:].toarray()
            self._z = self._band_solve(self._c) if g else np.zeros((nb_, 0))
        else:
            self._lower = np.zeros((1, 0))
            self._c = np.zeros((0, g))
            self._z = np.zeros((0, g))
        d = mat[nb_:, nb_:].toarray()
        self.schur = d - self._c.T @ self._z  # S = D − Cᵀ B⁻¹ C
        """The Schur complement ``S = D − Cᵀ B⁻¹ C`` (its inverse is the border covariance)."""
        if g:
            try:
                self._schur_factor = sla.cho_factor(self.schur, lower=True)
            except (np.linalg.LinAlgError, ValueError) as exc:
                raise NotPositiveDefiniteError(f"border (Schur complement): {exc}") from None
            self._w = sla.cho_solve(self._schur_factor, self._z.T).T  # W = Z S⁻¹
        else:
            self._w = np.zeros((nb_, 0))

    @property
    def size(self) -> int:
        return self.n_band + self.n_border

    def _band_solve(self, rhs: np.ndarray) -> np.ndarray:
        return sla.cho_solve_banded((self._lower, True), rhs, check_finite=False)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``N⁻¹ rhs`` for a vector ``(n,)`` or a matrix ``(n, k)`` of right-hand sides."""
        rhs = np.asarray(rhs, dtype=float)
        nb_ = self.n_band
        rb, rg = rhs[:nb_], rhs[nb_:]
        yb = self._band_solve(rb) if nb_ else rb.copy()
        if not self.n_border:
            return yb
        xg = sla.cho_solve(self._schur_factor, rg - self._z.T @ rb)  # S x_g = n_g − Zᵀ n_b
        xb = yb - self._z @ xg  # x_b = B⁻¹ n_b − Z x_g
        return np.concatenate([xb, xg], axis=0)

    def border_covariance(self) -> np.ndarray:
        """``(N⁻¹)_gg = S⁻¹``, the border block of the inverse (g × g)."""
        if not self.n_border:
            return np.zeros((0, 0))
        return sla.cho_solve(self._schur_factor, np.eye(self.n_border))

    def inverse_band(self, half_width: int | None = None) -> np.ndarray:
        """Band of ``(N⁻¹)_bb`` in lower storage ``out[k, j] = (N⁻¹)[j + k, j]``, k = 0 … q
        (default q = the bandwidth; a wider band is allowed)."""
        q = self.bandwidth if half_width is None else max(int(half_width), self.bandwidth)
        nb_ = self.n_band
        if not nb_:
            return np.zeros((q + 1, 0))
        band = takahashi_band(np.ascontiguousarray(self._lower), q)
        if self.n_border:
            for k in range(min(q, nb_ - 1) + 1):  # + (W Zᵀ)[j + k, j]
                band[k, : nb_ - k] += np.einsum("ij,ij->i", self._w[k:], self._z[: nb_ - k])
        return band

    def inverse_diagonal(self) -> np.ndarray:
        """Diagonal of ``N⁻¹`` (band then border), without forming the inverse."""
        band = self.inverse_band()[0] if self.n_band else np.zeros(0)
        return np.concatenate([band, np.diag(self.border_covariance())])

    def band_border_inverse(self) -> np.ndarray:
        """``(N⁻¹)_bg = −W = −B⁻¹ C S⁻¹`` (n_b × g)."""
        return -self._w

    def _band_matrix(self, half_width: int | None) -> sp.csr_matrix:
        """The band of ``(N⁻¹)_bb`` as a sparse symmetric matrix (cached per width)."""
        q = self.bandwidth if half_width is None else max(int(half_width), self.bandwidth)
        cached = self._band_cache.get(q)
        if cached is not None:
            return cached
        nb_ = self.n_band
        band = self.inverse_band(q)
        offsets, diags = [], []
        for k in range(min(q, nb_ - 1) + 1 if nb_ else 0):
            offsets += [-k] if k == 0 else [-k, k]
            diags += [band[k, : nb_ - k]] if k == 0 else [band[k, : nb_ - k]] * 2
        mat = (
            sp.diags(diags, offsets, shape=(nb_, nb_), format="csr")
            if diags
            else sp.csr_matrix((nb_, nb_))
        )
        self._band_cache[q] = mat
        return mat

    def selected_inverse(self, half_width: int | None = None) -> sp.csr_matrix:
        """``N⁻¹`` on the band (half width q ≥ bandwidth) and the whole border, as a sparse
        symmetric matrix; entries off that pattern are absent (not zero in N⁻¹)."""
        nb_, g = self.n_band, self.n_border
        band = self._band_matrix(half_width)
        wb = sp.csr_matrix(self.band_border_inverse())
        return sp.csr_matrix(
            sp.bmat([[band, wb], [wb.T, sp.csr_matrix(self.border_covariance())]])
            if g and nb_
            else (band if nb_ else sp.csr_matrix(self.border_covariance()))
        )

    def row_quadratic_forms(
        self, rows: sp.spmatrix | sp.sparray, half_width: int | None = None
    ) -> np.ndarray:
        """``a_iᵀ N⁻¹ a_i`` for every row ``a_i`` of a sparse (m × n) matrix::

            a_bᵀ (N⁻¹)_bb a_b  −  2 a_bᵀ W a_g  +  a_gᵀ S⁻¹ a_g

        from the band of the inverse (half width q, default the bandwidth) and the border
        blocks, one compiled pass over the non-zeros. Raises ``ValueError`` if a row holds two
        band columns farther apart than q (pass a wider ``half_width``).
        """
        a = sp.csr_matrix(rows)
        a.sum_duplicates()
        q = self.bandwidth if half_width is None else max(int(half_width), self.bandwidth)
        band = self._band_cache_raw.get(q)
        if band is None:
            band = self._band_cache_raw[q] = self.inverse_band(q)
        out, complete = _row_quadratic_forms(
            a.indptr,
            a.indices,
            a.data.astype(float),
            self.n_band,
            band,
            np.ascontiguousarray(self._w),
            np.ascontiguousarray(self.border_covariance()),
        )
        if not complete:
            raise ValueError(f"a row spans more than the half width {q} of the selected band")
        return out
