r"""Sparse weighted least squares, iterated with variance components and robust epoch weights
(docs/least_squares.md).

A problem hands the core its *linearization* at the current Taylor point: observation groups,
each with a sparse design ``A`` (m × u), reduced observations ``l = observed − computed``, an
a-priori sigma per row and labels (variance component, robust epoch), plus an optional prior on
the step. The core whitens the rows with ``σ_row · f_c · f_e``, forms::

    N = Σ_g Āᵀ Ā + N_prior,    n = Σ_g Āᵀ l̄ + n_prior,    Ā = diag(1/σ) A,  l̄ = l / σ

solves ``N dx = n`` banded with a border (:mod:`qkf.core.banded`), and computes per row the
redundancy number ``r_i = 1 − ā_iᵀ N⁻¹ ā_i`` from the selected inverse (no dense inverse), which
the variance-component and Huber step (:mod:`qkf.core.vce`) needs. :func:`iterate` repeats
linearize → solve → update → estimate until ``σ₀ = sqrt((l̄ᵀl̄ − dxᵀn)/(n_obs − u))`` changes by
less than a tolerance, or the iteration count is reached.

Parameters are ordered ``[band | border]``: the first ``n_band`` form the banded block (for
example one small rotation per epoch), the rest are global (biases, calibration). A problem with
no band (``n_band = 0``) is solved as one dense block, so small problems use the same machinery.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from qkf.core.banded import BandedBorderedCholesky, NotPositiveDefiniteError, half_bandwidth
from qkf.core.vce import RobustSettings, estimate_group

__all__ = [
    "BandedBorderedCholesky",
    "IterationInfo",
    "IterationResult",
    "IterationSettings",
    "Linearization",
    "NormalEquations",
    "NotPositiveDefiniteError",
    "ObservationGroup",
    "design_bandwidth",
    "iterate",
    "leverages",
    "normal_equations",
    "solve_normal",
    "whiten",
]


@dataclass(frozen=True)
class ObservationGroup:
    """Rows of one kind of observation.

    ``design`` (m × u, sparse) and ``residual`` (m,) are the linearised observation equations
    ``residual ≈ design · dx``; ``sigma`` (m,) the a-priori standard deviation of each row (same
    unit as ``residual``); ``component`` (m,) the variance component of each row, an index into
    ``component_names``; ``epoch`` (m,) the robust unit of each row (rows of one epoch get one
    Huber factor; default: every row its own).
    """

    name: str
    design: sp.csr_matrix
    residual: np.ndarray
    sigma: np.ndarray
    component: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    epoch: np.ndarray | None = None
    component_names: tuple[str, ...] = ("all",)

    def __post_init__(self) -> None:
        m = self.residual.shape[0]
        if self.design.shape[0] != m or self.sigma.shape != (m,):
            raise ValueError(f"group {self.name}: design, residual and sigma disagree in rows")
        if self.component.size == 0 and m:
            object.__setattr__(self, "component", np.zeros(m, dtype=np.int64))
        if self.component.shape != (m,):
            raise ValueError(f"group {self.name}: one component label per row")
        if m and (self.component.min() < 0 or self.component.max() >= len(self.component_names)):
            raise ValueError(f"group {self.name}: component label out of range")
        if self.epoch is None:
            object.__setattr__(self, "epoch", np.arange(m, dtype=np.int64))
        if not (np.all(np.isfinite(self.residual)) and np.all(np.isfinite(self.design.data))):
            raise ValueError(f"group {self.name}: non-finite residual or design entry")
        if not np.all(self.sigma > 0.0):
            raise ValueError(f"group {self.name}: sigma must be positive")

    @property
    def rows(self) -> int:
        return int(self.residual.shape[0])

    @property
    def epochs(self) -> np.ndarray:
        assert self.epoch is not None
        return self.epoch

    @property
    def n_epochs(self) -> int:
        return int(self.epochs.max()) + 1 if self.rows else 0


@dataclass(frozen=True)
class Linearization:
    """Everything one iteration solves: the groups, the parameter count and band size, and an
    optional prior on the step ``dx`` (not part of the variance estimation): ``prior_normal``
    (u,) diagonal weights or a sparse (u × u) matrix added to N, ``prior_rhs`` (u,) added to n."""

    groups: list[ObservationGroup]
    n_params: int
    n_band: int = 0
    prior_normal: np.ndarray | sp.spmatrix | None = None
    prior_rhs: np.ndarray | None = None


@dataclass(frozen=True)
class NormalEquations:
    """``N`` (sparse, u × u), ``n`` (u,), ``l̄ᵀl̄`` and the observation count behind them."""

    matrix: sp.csr_matrix
    rhs: np.ndarray
    lpl: float
    n_obs: int


def whiten(group: ObservationGroup, row_sigma: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """``Ā = diag(1/σ) A`` and ``l̄ = l/σ`` for the sigma of each row."""
    a = sp.csr_matrix(group.design, copy=True)
    a.data *= np.repeat(1.0 / row_sigma, np.diff(a.indptr))
    return a, group.residual / row_sigma


def normal_equations(
    whitened: list[tuple[sp.csr_matrix, np.ndarray]],
    n_params: int,
    prior_normal: np.ndarray | sp.spmatrix | None = None,
    prior_rhs: np.ndarray | None = None,
) -> NormalEquations:
    """``N = Σ ĀᵀĀ + N_prior`` and ``n = Σ Āᵀl̄ + n_prior`` from whitened groups."""
    mat = sp.csr_matrix((n_params, n_params))
    rhs = np.zeros(n_params)
    lpl, n_obs = 0.0, 0
    for a, l in whitened:
        at = a.T.tocsr()
        mat = mat + at @ a
        rhs += at @ l
        lpl += float(l @ l)
        n_obs += l.size
    if prior_normal is not None:
        mat = mat + (
            sp.diags(prior_normal) if isinstance(prior_normal, np.ndarray) else prior_normal
        )
    if prior_rhs is not None:
        rhs += prior_rhs
    return NormalEquations(sp.csr_matrix(mat), rhs, lpl, n_obs)


def design_bandwidth(design: sp.spmatrix | sp.sparray, n_band: int) -> int:
    """Largest column distance between band columns of one row: the half bandwidth that
    ``ĀᵀĀ`` needs, whatever cancels numerically."""
    a = sp.csr_matrix(design)
    counts = np.diff(a.indptr)
    if not a.nnz:
        return 0
    inside = a.indices < n_band
    starts = a.indptr[:-1][counts > 0]
    hi = np.maximum.reduceat(np.where(inside, a.indices, -1), starts)
    lo = np.minimum.reduceat(np.where(inside, a.indices, n_band), starts)
    ok = hi >= 0
    return int(np.max(hi[ok] - lo[ok])) if ok.any() else 0


def solve_normal(
    normal: NormalEquations, n_band: int, min_bandwidth: int = 0
) -> tuple[np.ndarray, BandedBorderedCholesky]:
    """Solve ``N dx = n`` with the banded-bordered Cholesky; returns ``(dx, factor)``."""
    p = max(half_bandwidth(normal.matrix, n_band), min_bandwidth)
    factor = BandedBorderedCholesky(normal.matrix, n_band, p)
    return factor.solve(normal.rhs), factor


def leverages(
    whitened_design: sp.spmatrix | sp.sparray,
    factor: BandedBorderedCholesky,
    half_width: int | None = None,
) -> np.ndarray:
    """``h_i = ā_iᵀ N⁻¹ ā_i`` per row of a whitened design; the redundancy number is
    ``r_i = 1 − h_i``. Needs only the band of N⁻¹ (half width at least the design's, see
    :func:`design_bandwidth`) and the border blocks, never the whole inverse."""
    return factor.row_quadratic_forms(whitened_design, half_width)


@dataclass(frozen=True)
class IterationSettings:
    """``max_iterations`` (GROOPS iterationCount, 15); stop when σ₀ changes by less than
    ``tolerance`` (1e-5); ``variance_components`` on/off; ``robust`` Huber settings
    (``RobustSettings(huber=None)``: off)."""

    max_iterations: int = 15
    tolerance: float = 1e-5
    variance_components: bool = True
    robust: RobustSettings = field(default_factory=RobustSettings)

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValueError("max_iterations must be at least 1")


@dataclass(frozen=True)
class IterationInfo:
    """Passed to the ``on_iteration`` callback after each iteration."""

    iteration: int
    sigma0: float
    component_sigma: dict[str, np.ndarray]
    step_norm: float


@dataclass
class IterationResult:
    """What :func:`iterate` leaves: the last factor (covariance: ``factor`` methods, for the
    weights of the last solve), the factors of every group after the last estimate, per-row
    residuals and redundancy numbers of the last solve, and the σ₀ history."""

    converged: bool
    iterations: int
    sigma0: list[float]
    component_sigma: dict[str, np.ndarray]
    epoch_sigma: dict[str, np.ndarray]
    factor: BandedBorderedCholesky
    step: np.ndarray
    residual: dict[str, np.ndarray]  # e = l − A dx (unit of the observations)
    redundancy: dict[str, np.ndarray]
    row_sigma: dict[str, np.ndarray]  # σ of each row in the last solve
    epoch_statistic: dict[str, np.ndarray]


def _row_sigma(
    g: ObservationGroup, f_c: dict[str, np.ndarray], f_e: dict[str, np.ndarray]
) -> np.ndarray:
    if g.name not in f_c:
        f_c[g.name] = np.ones(len(g.component_names))
    if g.name not in f_e or f_e[g.name].size != g.n_epochs:
        f_e[g.name] = np.ones(g.n_epochs)
    return g.sigma * f_c[g.name][g.component] * f_e[g.name][g.epochs]


def iterate(
    linearize: Callable[[], Linearization],
    update: Callable[[np.ndarray], None],
    settings: IterationSettings = IterationSettings(),
    on_iteration: Callable[[IterationInfo], None] | None = None,
    component_sigma: dict[str, np.ndarray] | None = None,
) -> IterationResult:
    """Gauss–Newton with variance components and Huber reweighting.

    Each iteration: ``lin = linearize()`` at the current Taylor point; whiten with the current
    factors; solve; ``update(dx)`` (the caller moves its Taylor point); residuals
    ``e = l − A dx`` and redundancy numbers of every group; then per group the variance
    components (if enabled) and the epoch factors (if ``robust.huber``). Stops when
    ``|σ₀ − σ₀_previous| < tolerance`` (never after the first iteration) or after
    ``max_iterations``. ``component_sigma`` gives starting factors per group (default 1).
    Raises :class:`NotPositiveDefiniteError` if a normal matrix cannot be factored.
    """
    f_c = {k: np.asarray(v, float).copy() for k, v in (component_sigma or {}).items()}
    f_e: dict[str, np.ndarray] = {}
    history: list[float] = []
    sigma0_prev = np.nan
    converged = False
    for it in range(1, settings.max_iterations + 1):
        lin = linearize()
        row_sigma = {g.name: _row_sigma(g, f_c, f_e) for g in lin.groups}
        white = [whiten(g, row_sigma[g.name]) for g in lin.groups]
        normal = normal_equations(white, lin.n_params, lin.prior_normal, lin.prior_rhs)
        p = max([design_bandwidth(a, lin.n_band) for a, _ in white] + [0])
        dx, factor = solve_normal(normal, lin.n_band, p)
        if not np.all(np.isfinite(dx)):
            raise NotPositiveDefiniteError("non-finite solution")
        update(dx)
        dof = max(normal.n_obs - lin.n_params, 1)
        sigma0 = float(np.sqrt(max(normal.lpl - float(dx @ normal.rhs), 0.0) / dof))
        history.append(sigma0)
        residual, redundancy, statistic = {}, {}, {}
        for g, (a, _) in zip(lin.groups, white, strict=True):
            e = g.residual - g.design @ dx
            r = 1.0 - leverages(a, factor, p)
            residual[g.name], redundancy[g.name] = e, r
            est = estimate_group(
                e,
                g.sigma,
                g.component,
                g.epochs,
                r,
                f_c[g.name],
                f_e[g.name],
                settings.variance_components,
                settings.robust,
            )
            f_c[g.name] = est.component_sigma
            f_e[g.name] = est.epoch_sigma
            statistic[g.name] = est.epoch_statistic
        if on_iteration is not None:
            on_iteration(IterationInfo(it, sigma0, dict(f_c), float(np.linalg.norm(dx))))
        if abs(sigma0 - sigma0_prev) < settings.tolerance:
            converged = True
            break
        sigma0_prev = sigma0
    return IterationResult(
        converged=converged,
        iterations=it,
        sigma0=history,
        component_sigma=f_c,
        epoch_sigma=f_e,
        factor=factor,
        step=dx,
        residual=residual,
        redundancy=redundancy,
        row_sigma=row_sigma,
        epoch_statistic=statistic,
    )
