r"""Gauss–Newton solution, covariance and observability of the alignment calibration
(docs/alignment.md).

Unknowns: ``x`` = the alignments ``θ_s`` (3 each, rad) of every sensor but the reference
(``θ_ref = 0`` defines the body frame). Prior: ``x ~ N(0, P₀)``, ``P₀ = diag(prior²)``, a
pseudo-observation. Each pass linearises about the current ``θ`` with the exact rotations
(:mod:`qkf.alignment.model`), whitens every epoch's pairs with their full covariance and
solves::

    N = Σ_e H̃ₑᵀ H̃ₑ + P₀⁻¹,    N dx = Σ_e H̃ₑᵀ z̃ₑ − P₀⁻¹ x,    x ← x + dx

(in units scaled by the prior sigmas, by Cholesky). It stops when every component of ``dx`` is
below ``solver.tolerance`` times its standard deviation. The covariance is ``N⁻¹`` at the
solution.

Observability: the data-only information ``N_d = Σ H̃ᵀH̃``, scaled by the prior sigmas
(``Ñ = D N_d D``, the prior is then the identity), has eigenvalues ``λ̃``; along an eigenvector
the posterior information is ``λ̃ + 1`` of which the prior supplies ``1/(1 + λ̃)``. A direction
is *rank-deficient* when ``λ̃ < rank_tolerance · max λ̃`` and *prior-determined* when the prior's
share exceeds ``observability.prior_share``; its estimate there is the prior's, not the data's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from qkf.alignment.config import AlignmentConfig, Observability
from qkf.alignment.data import Observations
from qkf.alignment.model import (
    Pairs,
    form_pairs,
    jacobian,
    pair_covariance,
    residuals,
    rotated,
    to_blocks,
    whitening,
)
from qkf.core import units


class SolveError(RuntimeError):
    """The normal equations could not be solved (not positive definite, not finite)."""


@dataclass(frozen=True)
class Direction:
    """One eigen-direction of the data information (in the prior-scaled unknowns).

    ``vector`` (3·m,) the unit direction in the unknowns (rad); ``axes`` per free sensor its
    part: ``(name, unit axis in body axes, share of the direction)``; ``scaled`` the eigenvalue
    ``λ̃`` (data information relative to the prior's along it), ``relative`` ``λ̃ / max λ̃``,
    ``information`` the data information along ``vector`` (1/rad²), ``prior_information`` the
    prior's, ``sd`` and ``prior_sd`` the posterior and prior 1-σ along ``vector`` (rad)."""

    vector: np.ndarray
    axes: list[tuple[str, np.ndarray, float]]
    scaled: float
    relative: float
    information: float
    prior_information: float
    sd: float
    prior_sd: float
    rank_deficient: bool
    prior_determined: bool

    @property
    def unobservable(self) -> bool:
        return self.rank_deficient or self.prior_determined


@dataclass(frozen=True)
class Solution:
    """Result of :func:`solve` (SI: rad).

    ``theta`` (S, 3) alignments of every sensor (the reference's zero), ``sd`` (S, 3) their 1-σ
    (zero for the reference), ``cov`` (3m, 3m) the covariance of the free sensors' alignments
    (``free`` their indices, config order), ``prior_sd`` (S, 3), ``history`` (passes + 1, S, 3)
    the iterates, ``directions`` the eigen-directions of the data information, weakest first.
    Residuals at the solution, per pair: ``pair_t`` (s), ``pair_type`` (index into
    ``pair_types``), ``z`` (dimensionless), ``z_sd`` (its standard deviation), ``angle`` (``z``
    as an angle, ``z / |u_a × u_b|``, rad); ``chi2`` the whitened residual sum over ``rows``
    independent rows.
    """

    names: tuple[str, ...]
    reference: str
    free: list[int]
    theta: np.ndarray
    sd: np.ndarray
    cov: np.ndarray
    prior_sd: np.ndarray
    history: np.ndarray
    steps: list[float]
    converged: bool
    rank: int
    directions: list[Direction]
    n_observations: int
    n_epochs: int
    pair_types: list[str]
    pair_t: np.ndarray
    pair_type: np.ndarray
    z: np.ndarray
    z_sd: np.ndarray
    angle: np.ndarray
    chi2: float
    rows: int
    info_data: np.ndarray = field(repr=False)

    @property
    def iterations(self) -> int:
        return len(self.steps)

    @property
    def n_unknowns(self) -> int:
        return 3 * len(self.free)

    @property
    def n_pairs(self) -> int:
        return int(self.z.size)

    @property
    def prior_share(self) -> np.ndarray:
        """Posterior variance over prior variance per sensor and axis (S, 3): near 1 where the
        prior alone fixes that component (0 for the reference)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            share = (self.sd / np.where(self.prior_sd > 0, self.prior_sd, 1.0)) ** 2
        return np.where(self.prior_sd > 0, share, 0.0)

    def unobservable(self) -> list[Direction]:
        return [d for d in self.directions if d.unobservable]


@dataclass
class _Linearization:
    z: np.ndarray  # (P,)
    h: np.ndarray  # (P, 3m)
    zw: np.ndarray  # (E, W) whitened
    hw: np.ndarray  # (E, W, 3m) whitened
    cov: np.ndarray  # (E, W, W)
    rank: np.ndarray  # (E,)
    u: np.ndarray  # (n, 3)


def _linearize(
    theta: np.ndarray,
    obs: Observations,
    pairs: Pairs,
    free: list[int],
    sigma: np.ndarray,
    correlated: bool,
) -> _Linearization:
    u = rotated(theta, obs)
    z = residuals(u, obs, pairs)
    h = jacobian(theta, u, obs, pairs, free)
    cov = pair_covariance(u, sigma, obs, pairs, correlated)
    w, rank = whitening(cov)
    zw = np.einsum("eij,ej->ei", w, to_blocks(z, pairs))
    hw = np.einsum("eij,ejk->eik", w, to_blocks(h, pairs))
    return _Linearization(z, h, zw, hw, cov, rank, u)


def _embed(x: np.ndarray, free: list[int], n_sensors: int) -> np.ndarray:
    theta = np.zeros((n_sensors, 3))
    theta[free] = x.reshape(-1, 3)
    return theta


def solve(cfg: AlignmentConfig, obs: Observations) -> Solution:
    """Gauss–Newton alignment calibration of the sensors of ``cfg`` from ``obs``."""
    names = list(cfg.names)
    if tuple(names) != obs.names:
        raise ValueError(f"observations are for sensors {obs.names}, the config has {names}")
    ref = names.index(cfg.reference)
    free = [i for i in range(len(names)) if i != ref]
    sigma = np.array([s.sigma_arcsec * units.ARCSEC for s in cfg.sensors])
    prior = np.array([cfg.prior_deg_of(s) * units.DEG for s in cfg.sensors])
    d = np.repeat(prior[free], 3)  # prior sigma per unknown
    pairs = form_pairs(obs, cfg.data.time_tolerance_s)
    if pairs.n == 0:
        raise SolveError("no two sensors are ever observed at the same time: nothing to solve")
    sv = cfg.solver
    x = np.zeros(3 * len(free))
    history = [_embed(x, free, len(names))]
    steps: list[float] = []
    converged = False
    for _ in range(sv.max_iterations):
        lin = _linearize(history[-1], obs, pairs, free, sigma, sv.correlated_pairs)
        dx, cov_s = _step(lin, x, d)
        sd_s = np.sqrt(np.diag(cov_s))
        step = float(np.max(np.abs(dx / d) / sd_s))
        x = x + dx
        history.append(_embed(x, free, len(names)))
        steps.append(step)
        if step < sv.tolerance:
            converged = True
            break
    # covariance, observability and residuals at the solution
    lin = _linearize(history[-1], obs, pairs, free, sigma, sv.correlated_pairs)
    _, cov_s = _step(lin, x, d)
    cov = cov_s * np.outer(d, d)
    info_data = np.einsum("eik,eil->kl", lin.hw, lin.hw)
    directions = _directions(info_data, cov, d, names, free, cfg.observability)
    rank = sum(not di.rank_deficient for di in directions)
    theta = history[-1]
    sd = np.zeros((len(names), 3))
    sd[free] = np.sqrt(np.diag(cov)).reshape(-1, 3)
    prior_sd = np.repeat(prior[:, None], 3, axis=1)
    prior_sd[ref] = 0.0
    types, pair_type = _pair_types(obs, pairs, names)
    z_sd = np.sqrt(np.diagonal(lin.cov, axis1=1, axis2=2)[pairs.epoch, pairs.slot])
    n_cross = np.linalg.norm(np.cross(lin.u[pairs.a], lin.u[pairs.b]), axis=1)
    return Solution(
        names=tuple(names),
        reference=cfg.reference,
        free=free,
        theta=theta,
        sd=sd,
        cov=cov,
        prior_sd=prior_sd,
        history=np.stack(history),
        steps=steps,
        converged=converged,
        rank=rank,
        directions=directions,
        n_observations=obs.n,
        n_epochs=pairs.n_epochs,
        pair_types=types,
        pair_t=pairs.epoch_t[pairs.epoch],
        pair_type=pair_type,
        z=lin.z,
        z_sd=z_sd,
        angle=lin.z / np.maximum(n_cross, 1e-300),
        chi2=float(np.sum(lin.zw**2)),
        rows=int(lin.rank.sum()),
        info_data=info_data,
    )


def _step(lin: _Linearization, x: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Newton step ``dx`` (rad) and ``N⁻¹`` in units scaled by ``d``."""
    hs = lin.hw * d  # scaled columns
    n_mat = np.einsum("eik,eil->kl", hs, hs) + np.eye(d.size)
    rhs = np.einsum("eik,ei->k", hs, lin.zw) - x / d
    if not (np.all(np.isfinite(n_mat)) and np.all(np.isfinite(rhs))):
        raise SolveError("non-finite normal equations (check the input vectors)")
    try:
        factor = scipy.linalg.cho_factor(n_mat)
    except np.linalg.LinAlgError:
        raise SolveError("normal matrix not positive definite") from None
    dx = scipy.linalg.cho_solve(factor, rhs) * d
    # covariance of a small (3m × 3m) problem: the inverse from the factor
    cov = scipy.linalg.cho_solve(factor, np.eye(d.size))
    return dx, 0.5 * (cov + cov.T)


def _directions(
    info: np.ndarray,
    cov: np.ndarray,
    d: np.ndarray,
    names: list[str],
    free: list[int],
    settings: Observability,
) -> list[Direction]:
    rank_tol, share_max = settings.rank_tolerance, settings.prior_share
    scaled = info * np.outer(d, d)
    lam, vec = np.linalg.eigh(0.5 * (scaled + scaled.T))
    top = max(float(lam[-1]), np.finfo(float).tiny)
    out = []
    for k in range(lam.size):
        v = vec[:, k] * d  # physical direction
        v = v / np.linalg.norm(v)
        if v[np.argmax(np.abs(v))] < 0:
            v = -v
        axes = []
        for j, s in enumerate(free):
            part = v[3 * j : 3 * j + 3]
            share = float(part @ part)
            if share > 1e-3:
                axes.append((names[s], part / np.sqrt(share), share))
        lam_k = max(float(lam[k]), 0.0)
        prior_info = float(v @ (v / d**2))
        out.append(
            Direction(
                vector=v,
                axes=axes,
                scaled=lam_k,
                relative=lam_k / top,
                information=float(v @ info @ v),
                prior_information=prior_info,
                sd=float(np.sqrt(v @ cov @ v)),
                prior_sd=float(np.sqrt(v @ (v * d**2))),
                rank_deficient=lam_k < rank_tol * top,
                prior_determined=1.0 / (1.0 + lam_k) > share_max,
            )
        )
    return out


def _pair_types(obs: Observations, pairs: Pairs, names: list[str]) -> tuple[list[str], np.ndarray]:
    sa, sb = obs.sensor[pairs.a], obs.sensor[pairs.b]
    code = sa * len(names) + sb
    used = np.unique(code)
    labels = [f"{names[c // len(names)]}–{names[c % len(names)]}" for c in used]
    return labels, np.searchsorted(used, code)
