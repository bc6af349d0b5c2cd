r"""Measurement model of attitude-independent alignment calibration (docs/alignment.md).

Sensor ``s`` reports ``w`` in the body frame through its nominal mounting; its true body-frame
direction is ``u = Exp(θ_s) w``. For observations ``a`` and ``b`` of two sensors at one epoch
the angle between the directions does not depend on the attitude::

    r_a · r_b = (Exp(θ_a) w_a) · (Exp(θ_b) w_b)

so the pair residual and its Jacobian at the current ``θ`` are (``u = Exp(θ) w``, ``J_l`` the
left Jacobian of SO(3), ``Exp(θ + dθ) ≈ Exp(J_l(θ) dθ) Exp(θ)``)::

    z_ab = r_a·r_b − u_a·u_b ≈ (u_a × u_b)ᵀ J_l(θ_a) dθ_a − (u_a × u_b)ᵀ J_l(θ_b) dθ_b

Noise: a reported vector carries a small rotation error, ``σ`` per axis perpendicular to it,
so ``u + ε`` with ``Cov ε = σ² (I − u uᵀ)``. To first order ``z_ab`` changes by
``−(ε_a·u_b + u_a·ε_b)``, hence::

    Var z_ab = (σ_a² + σ_b²) |u_a × u_b|²     (+ second-order terms, see pair_covariance)
    Cov(z_ab, z_ac) = σ_a² (u_a × u_b)·(u_a × u_c)     (pairs sharing observation a)

Pairs of one epoch that share an observation are correlated; their covariance is a full block
per epoch, of rank at most 2m − 3 for m vectors to first order (a common rotation changes no
angle). Pairs are formed between observations of different sensors only (the angle between
two vectors of one sensor does not depend on its alignment).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.alignment.data import Observations, epoch_index
from qkf.core.so3 import exp_matrix, left_jacobian


@dataclass(frozen=True)
class Pairs:
    """Observation pairs ``(a, b)`` (indices into the observations, sensor of a before sensor of
    b in config order) at the same epoch. ``epoch`` (P,) their epoch, ``slot`` (P,) their place
    inside the epoch's block of ``width`` pairs, ``n_epochs`` the epochs holding a pair,
    ``epoch_t`` (n_epochs,) their times."""

    a: np.ndarray
    b: np.ndarray
    epoch: np.ndarray
    slot: np.ndarray
    n_epochs: int
    width: int
    epoch_t: np.ndarray

    @property
    def n(self) -> int:
        return int(self.a.size)


def form_pairs(obs: Observations, time_tolerance_s: float) -> Pairs:
    """Every pair of observations of different sensors at one epoch."""
    epoch, times = epoch_index(obs.t, time_tolerance_s)
    order = np.lexsort((np.arange(obs.n), obs.sensor, epoch))
    a_list: list[np.ndarray] = []
    b_list: list[np.ndarray] = []
    bounds = np.flatnonzero(np.diff(epoch[order])) + 1
    upper: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for group in np.split(order, bounds):
        if group.size < 2:
            continue
        if group.size not in upper:
            upper[group.size] = np.triu_indices(group.size, k=1)
        ia, ib = upper[group.size]
        keep = obs.sensor[group[ia]] != obs.sensor[group[ib]]
        a_list.append(group[ia[keep]])
        b_list.append(group[ib[keep]])
    if not a_list:
        empty = np.empty(0, dtype=np.int64)
        return Pairs(empty, empty, empty, empty, 0, 0, np.empty(0))
    a = np.concatenate(a_list)
    b = np.concatenate(b_list)
    ep_raw = epoch[a]
    used, ep = np.unique(ep_raw, return_inverse=True)
    counts = np.bincount(ep)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    order_p = np.argsort(ep, kind="stable")
    slot = np.empty(a.size, dtype=np.int64)
    slot[order_p] = np.arange(a.size) - np.repeat(start, counts)
    return Pairs(a, b, ep, slot, int(used.size), int(counts.max()), times[used])


def rotated(theta: np.ndarray, obs: Observations) -> np.ndarray:
    """Body-frame directions ``u = Exp(θ_s) w`` (n, 3) for alignments ``theta`` (S, 3) rad."""
    rot = exp_matrix(theta)  # (S, 3, 3)
    return np.einsum("nij,nj->ni", rot[obs.sensor], obs.w)


def residuals(u: np.ndarray, obs: Observations, pairs: Pairs) -> np.ndarray:
    """``z = r_a·r_b − u_a·u_b`` (P,), dimensionless."""
    ref = np.einsum("pi,pi->p", obs.r[pairs.a], obs.r[pairs.b])
    return ref - np.einsum("pi,pi->p", u[pairs.a], u[pairs.b])


def jacobian(
    theta: np.ndarray, u: np.ndarray, obs: Observations, pairs: Pairs, free: list[int]
) -> np.ndarray:
    """``∂z/∂θ`` (P, 3·len(free)) with respect to the alignments of the sensors ``free`` (in
    that order; other sensors' alignments are held fixed)."""
    col = {s: i for i, s in enumerate(free)}
    jl = left_jacobian(theta)  # (S, 3, 3)
    n = np.cross(u[pairs.a], u[pairs.b])  # (P, 3)
    out = np.zeros((pairs.n, 3 * len(free)))
    for end, sign in ((pairs.a, 1.0), (pairs.b, -1.0)):
        sens = obs.sensor[end]
        rows = sign * np.einsum("pi,pij->pj", n, jl[sens])
        for s, c in col.items():
            hit = sens == s
            out[hit, 3 * c : 3 * c + 3] = rows[hit]
    return out


def pair_covariance(
    u: np.ndarray,
    sigma: np.ndarray,
    obs: Observations,
    pairs: Pairs,
    correlated: bool = True,
    second_order: bool = True,
) -> np.ndarray:
    """Noise covariance of the pairs, one block per epoch: (n_epochs, width, width); entries of
    unused slots are zero. ``sigma`` (S,) rad per sensor. ``correlated=False`` keeps only the
    variances. ``second_order`` adds the second-order variance of each pair, from the product
    of the two noises and from the normalisation of the reported vectors,
    ``σ_a² σ_b² (1 + c²) + c² (σ_a⁴ + σ_b⁴)`` with ``c = u_a·u_b``: negligible unless
    ``|u_a × u_b|`` is of the order of the noise, where it keeps a nearly parallel pair from
    getting a near-infinite weight."""
    blocks = np.zeros((pairs.n_epochs, pairs.width, pairs.width))
    ends = np.full((pairs.n_epochs, pairs.width, 2), -1, dtype=np.int64)
    ends[pairs.epoch, pairs.slot, 0] = pairs.a
    ends[pairs.epoch, pairs.slot, 1] = pairs.b
    valid = ends[..., 0] >= 0
    sig2 = sigma[obs.sensor] ** 2  # (n,)
    u_pad = np.vstack([u, np.zeros((1, 3))])  # index −1 → zero vector
    idx = np.where(ends >= 0, ends, u.shape[0])
    for i in range(2):  # the shared observation is end i of pair p ...
        for j in range(2):  # ... and end j of pair q
            o_p = idx[:, :, i]  # (E, W)
            o_q = idx[:, :, j]
            shared = (o_p[:, :, None] == o_q[:, None, :]) & valid[:, :, None] & valid[:, None, :]
            if not correlated:
                shared &= np.eye(pairs.width, dtype=bool)[None]
            if not shared.any():
                continue
            u_o = u_pad[o_p]  # (E, W, 3)
            other_p = u_pad[idx[:, :, 1 - i]]
            other_q = u_pad[idx[:, :, 1 - j]]
            n_p = np.cross(u_o, other_p)  # (E, W, 3)
            n_q = np.cross(u_pad[o_q], other_q)
            s2 = np.concatenate([sig2, [0.0]])[o_p]  # (E, W)
            term = s2[:, :, None] * np.einsum("epk,eqk->epq", n_p, n_q)
            blocks += np.where(shared, term, 0.0)
    if second_order:
        cos = np.einsum("pi,pi->p", u[pairs.a], u[pairs.b])
        sa2, sb2 = sig2[pairs.a], sig2[pairs.b]
        extra = sa2 * sb2 * (1.0 + cos**2) + cos**2 * (sa2**2 + sb2**2)
        blocks[pairs.epoch, pairs.slot, pairs.slot] += extra
    return 0.5 * (blocks + np.swapaxes(blocks, -1, -2))


WHITENING_TOLERANCE = 1e-6
"""Eigen-directions of an epoch's pair covariance below this fraction of its largest eigenvalue
are dropped: they carry noise only at second order (about σ² of the largest) and, to first
order, no information on the alignments."""


def whitening(
    blocks: np.ndarray, rank_tolerance: float = WHITENING_TOLERANCE
) -> tuple[np.ndarray, np.ndarray]:
    """Per epoch a matrix ``W`` (E, width, width) with ``W Σ Wᵀ = I`` on the kept directions of
    ``Σ`` (rows of directions whose eigenvalue is below ``rank_tolerance`` × the largest are
    zero: pairs of an epoch can outnumber the noise they share), and the rank of each block."""
    lam, vec = np.linalg.eigh(blocks)
    top = np.max(lam, axis=-1, keepdims=True)
    keep = lam > rank_tolerance * np.maximum(top, np.finfo(float).tiny)
    scale = np.where(keep, 1.0 / np.sqrt(np.where(keep, lam, 1.0)), 0.0)
    return scale[:, :, None] * np.swapaxes(vec, -1, -2), keep.sum(axis=-1)


def to_blocks(values: np.ndarray, pairs: Pairs) -> np.ndarray:
    """Arrange per-pair values (P, ...) into epoch blocks (n_epochs, width, ...), zero-padded."""
    out = np.zeros((pairs.n_epochs, pairs.width, *values.shape[1:]))
    out[pairs.epoch, pairs.slot] = values
    return out
