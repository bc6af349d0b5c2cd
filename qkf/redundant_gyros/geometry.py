r"""Geometry of a redundant gyro unit (docs/redundant_gyros.md, "Model" and "Geometry").

Gyro i senses along ``w_i``; ``u_i`` ⟂ ``w_i`` is its reference axis and ``v_i = w_i × u_i``.
Its reading is

    m_i = (1 − λ_i) w̄_iᵀ ω − b_i − η_i,      w̄_i = w_i − δ_ui u_i − δ_vi v_i,

ω and b in deg/s, δ in rad, λ dimensionless. The known (nominal) errors are compensated as
``y_i = (m_i + b_i) / (1 − λ_i) = w̄_iᵀ ω − η_i / (1 − λ_i)``, so the detectors work on the
geometry ``G`` whose rows are the nominal ``w̄_i`` and on noise of sd ``σ_i / (1 − λ_i)``.

This module holds the matrices everything else uses: least-squares reconstruction per model,
the three-cross signatures, the parity matrix ``V`` (``V W = 0``, ``V Vᵀ = I``) and the report
of what the geometry cannot tell apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from typing import TYPE_CHECKING

import numpy as np

from qkf.core.units import DEG

if TYPE_CHECKING:
    from qkf.redundant_gyros.config import GyrosConfig

COEFFS = ("b", "lambda", "delta_u", "delta_v")
"""Order of the error coefficients of one gyro: bias (deg/s), λ, δ_u (rad), δ_v (rad)."""
RANK_TOL = 1e-9
"""Relative singular-value floor below which a set of axes is taken as rank deficient."""
ORTHOGONALITY_TOL = 1e-3
"""|cos(w, u)| above this is refused as a configuration error (not silently fixed)."""
COLLINEAR_COS = 1.0 - 1e-9
"""Parity columns with |cos| above this cannot be told apart by the GLT at all."""
WEAK_COS = 0.9
"""Parity columns with |cos| above this are reported as hard to tell apart (angle < 25.8°)."""


class GeometryError(ValueError):
    """A gyro unit or a model whose axes cannot work (degenerate, not orthogonal)."""


def axes_from_angles(alpha_deg: float, beta_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Sensing and reference axes of a gyro mounted at angles (α, β), deg."""
    a, b = alpha_deg * DEG, beta_deg * DEG
    w = np.array([np.sin(a) * np.sin(b), np.cos(a), np.sin(a) * np.cos(b)])
    u = np.array([-np.cos(a) * np.sin(b), np.sin(a), -np.cos(a) * np.cos(b)])
    return w, u


def true_axes(w: np.ndarray, u: np.ndarray, v: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """``w̄ = w − δ_u u − δ_v v`` for coefficient arrays ``(..., n, 4)``; returns ``(..., n, 3)``."""
    return w - coeffs[..., 2:3] * u - coeffs[..., 3:4] * v


def readings(
    w: np.ndarray, u: np.ndarray, v: np.ndarray, coeffs: np.ndarray, rate: np.ndarray
) -> np.ndarray:
    """Noise-free readings ``(1 − λ) w̄ᵀ ω − b`` (deg/s) for coefficients ``(..., n, 4)`` and body
    rates ``(..., 3)`` (deg/s); returns ``(..., n)``."""
    axis = true_axes(w, u, v, coeffs)
    return (1.0 - coeffs[..., 1]) * np.einsum("...nj,...j->...n", axis, rate) - coeffs[..., 0]


def least_squares_matrix(g: np.ndarray) -> np.ndarray:
    """``(Gᵀ G)⁻¹ Gᵀ`` for a ``k × 3`` geometry of rank 3 (via a QR solve, no explicit inverse)."""
    q, r = np.linalg.qr(g)
    return np.asarray(np.linalg.solve(r, q.T))


def parity_matrix(w: np.ndarray) -> np.ndarray:
    """``V`` ((n − 3) × n) with orthonormal rows spanning the left null space of ``W`` (n × 3):
    ``V W = 0``, ``V Vᵀ = I``, ``W (Wᵀ W)⁻¹ Wᵀ + Vᵀ V = I``. From a complete QR of ``W``."""
    q, _ = np.linalg.qr(w, mode="complete")
    return np.ascontiguousarray(q[:, 3:].T)


def rank3(g: np.ndarray) -> bool:
    """Whether the rows of ``g`` span 3-space (relative singular-value test)."""
    s = np.linalg.svd(g, compute_uv=False)
    return bool(s.size >= 3 and s[2] > RANK_TOL * max(s[0], 1e-300))


@dataclass(frozen=True)
class Separability:
    """What the geometry cannot tell apart (reported before any run)."""

    undetectable: list[str]  # a fault of this gyro never reaches the parity space
    glt_inseparable: list[tuple[str, str]]  # collinear parity columns
    glt_weak: list[tuple[str, str, float]]  # (i, j, angle in deg) with |cos| > WEAK_COS
    threecross_undefined: list[str]  # signature not finite (gyro in no or in identical models)
    threecross_close: list[tuple[str, str, float]]  # signatures closer than two bands
    threecross_unrecoverable: list[str]  # no model and no remaining triad excludes the gyro

    def lines(self) -> list[str]:
        """One line per finding (empty: everything separable)."""
        out = []
        if self.undetectable:
            out.append(f"GLT: faults of {', '.join(self.undetectable)} are undetectable")
        out += [f"GLT: {a} and {b} cannot be told apart" for a, b in self.glt_inseparable]
        out += [
            f"GLT: {a} and {b} are hard to tell apart (parity columns {ang:.1f}° apart)"
            for a, b, ang in self.glt_weak
        ]
        if self.threecross_undefined:
            out.append(
                f"three-cross: no finite signature for {', '.join(self.threecross_undefined)}"
            )
        out += [
            f"three-cross: {a} and {b} cannot be told apart (signatures {d:.3f} apart, "
            "less than two bands)"
            for a, b, d in self.threecross_close
        ]
        if self.threecross_unrecoverable:
            out.append(
                "reconfiguration: no healthy triad without "
                + ", ".join(self.threecross_unrecoverable)
            )
        return out


@dataclass(frozen=True)
class GyroUnit:
    """A configured unit in internal units (deg/s, rad). Arrays are indexed by gyro."""

    ids: tuple[str, ...]
    w: np.ndarray  # (n, 3) design sensing axes
    u: np.ndarray  # (n, 3)
    v: np.ndarray  # (n, 3) = w × u
    nominal: np.ndarray  # (n, 4) known coefficients [b deg/s, λ, δ_u rad, δ_v rad]
    noise: np.ndarray  # (n,) white-noise sd per sample, deg/s
    models: tuple[tuple[int, ...], ...]  # three-cross models as gyro indices
    band: float
    g: np.ndarray = field(init=False)  # (n, 3) compensated geometry: nominal w̄
    comp_noise: np.ndarray = field(init=False)  # (n,) noise sd after compensation
    model_ls: np.ndarray = field(init=False)  # (3 models, 3, n) LS rate matrices, embedded
    signature: np.ndarray = field(init=False)  # (n,) three-cross signatures of G
    v_parity: np.ndarray = field(init=False)  # (n − 3, n) parity matrix of the whitened G
    exclusion: tuple[tuple[str, np.ndarray], ...] = field(init=False)  # per gyro: name, (3, n)
    fusion: np.ndarray = field(init=False)  # (3, n) weighted fusion of the three models

    def __post_init__(self) -> None:
        g = true_axes(self.w, self.u, self.v, self.nominal)
        comp = self.noise / (1.0 - self.nominal[:, 1])
        mls = np.stack([embedded_ls(g, m) for m in self.models])
        fusion_w = np.array([1.0 / np.trace(p @ np.diag(comp**2) @ p.T) for p in mls])
        fusion_w /= fusion_w.sum()
        set_ = object.__setattr__
        set_(self, "g", g)
        set_(self, "comp_noise", comp)
        set_(self, "model_ls", mls)
        set_(self, "signature", signatures(mls))
        set_(self, "v_parity", parity_matrix(g / comp[:, None]))
        set_(self, "exclusion", tuple(self._exclusion(i) for i in range(self.n)))
        set_(self, "fusion", np.einsum("m,mjn->jn", fusion_w, mls))

    @property
    def n(self) -> int:
        return len(self.ids)

    def index(self, gid: str) -> int:
        return self.ids.index(gid)

    def model_name(self, m: tuple[int, ...]) -> str:
        return "".join(self.ids[i] for i in m)

    def _exclusion(self, i: int) -> tuple[str, np.ndarray]:
        """The estimator that leaves gyro i out: the first model without it, else all others."""
        for m, p in zip(self.models, self.model_ls, strict=True):
            if i not in m:
                return self.model_name(m), p
        rest = tuple(j for j in range(self.n) if j != i)
        if not rank3(self.g[list(rest)]):
            return "none", np.full((3, self.n), np.nan)
        return self.model_name(rest), embedded_ls(self.g, rest)

    def compensate(self, meas: np.ndarray) -> np.ndarray:
        """Readings (..., n) with the nominal bias and scale factor removed: ``(m + b)/(1 − λ)``."""
        return (meas + self.nominal[:, 0]) / (1.0 - self.nominal[:, 1])

    def readings(self, coeffs: np.ndarray, rate: np.ndarray) -> np.ndarray:
        """Noise-free readings for coefficients ``(..., n, 4)`` and rates ``(..., 3)``, deg/s."""
        return readings(self.w, self.u, self.v, coeffs, rate)

    def separability(self) -> Separability:
        v = self.v_parity
        norms = np.linalg.norm(v, axis=0)
        scale = max(float(norms.max(initial=0.0)), 1e-300)
        undetectable = [self.ids[i] for i in range(self.n) if norms[i] < 1e-9 * scale]
        inseparable, weak = [], []
        ok = [i for i in range(self.n) if self.ids[i] not in undetectable]
        for i, j in combinations(ok, 2):
            c = abs(float(v[:, i] @ v[:, j]) / (norms[i] * norms[j]))
            if c >= COLLINEAR_COS:
                inseparable.append((self.ids[i], self.ids[j]))
            elif c > WEAK_COS:
                weak.append((self.ids[i], self.ids[j], float(np.degrees(np.arccos(c)))))
        sig = self.signature
        undefined = [self.ids[i] for i in range(self.n) if not np.isfinite(sig[i])]
        close = [
            (self.ids[i], self.ids[j], float(abs(sig[i] - sig[j])))
            for i, j in combinations(range(self.n), 2)
            if np.isfinite(sig[i]) and np.isfinite(sig[j]) and abs(sig[i] - sig[j]) < 2 * self.band
        ]
        unrecoverable = [self.ids[i] for i in range(self.n) if self.exclusion[i][0] == "none"]
        return Separability(undetectable, inseparable, weak, undefined, close, unrecoverable)


def embedded_ls(g: np.ndarray, members: tuple[int, ...] | list[int]) -> np.ndarray:
    """The LS rate matrix of the gyros ``members`` as a (3, n) matrix (zero columns elsewhere)."""
    p = np.zeros((3, g.shape[0]))
    p[:, list(members)] = least_squares_matrix(g[list(members)])
    return p


def signatures(model_ls: np.ndarray) -> np.ndarray:
    """Three-cross signature of each gyro: ``‖c₁ᵢ − c₂ᵢ‖ / ‖c₁ᵢ − c₃ᵢ‖`` with ``c_mi`` the column
    of model m's LS matrix for gyro i (zero if the model leaves it out). A fault of gyro i alone
    moves model m's rate by ``c_mi f``, so the feature equals this whatever f and ω are."""
    num = np.linalg.norm(model_ls[0] - model_ls[1], axis=0)
    den = np.linalg.norm(model_ls[0] - model_ls[2], axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(num / den)


def build_unit(cfg: GyrosConfig) -> GyroUnit:
    """The unit of a config in internal units; :class:`GeometryError` names the offending part."""
    unit = cfg.unit
    nom = unit.nominal
    ws, us, coeffs, noise = [], [], [], []
    for k, spec in enumerate(unit.gyros):
        where = f"unit.gyros.{k}"
        if spec.w is not None and spec.u is not None:
            w, u = np.asarray(spec.w, dtype=float), np.asarray(spec.u, dtype=float)
            nw, nu = np.linalg.norm(w), np.linalg.norm(u)
            if nw == 0.0 or nu == 0.0:
                raise GeometryError(f"{where}: w and u must be non-zero vectors")
            w, u = w / nw, u / nu
            if abs(float(w @ u)) > ORTHOGONALITY_TOL:
                raise GeometryError(
                    f"{where}: u is not perpendicular to w (cos = {float(w @ u):.4g})"
                )
            u = u - (w @ u) * w
            u = u / np.linalg.norm(u)
        else:
            assert spec.alpha_deg is not None and spec.beta_deg is not None
            w, u = axes_from_angles(spec.alpha_deg, spec.beta_deg)
        ws.append(w)
        us.append(u)
        coeffs.append(
            [
                nom.bias_deg_s if spec.bias_deg_s is None else spec.bias_deg_s,
                nom.scale if spec.scale is None else spec.scale,
                (nom.delta_u_deg if spec.delta_u_deg is None else spec.delta_u_deg) * DEG,
                (nom.delta_v_deg if spec.delta_v_deg is None else spec.delta_v_deg) * DEG,
            ]
        )
        noise.append(unit.noise_deg_s if spec.noise_deg_s is None else spec.noise_deg_s)
    w_arr, u_arr = np.array(ws), np.array(us)
    ids = tuple(unit.ids())
    nominal = np.array(coeffs)
    g = true_axes(w_arr, u_arr, np.cross(w_arr, u_arr), nominal)
    if not rank3(g):
        raise GeometryError("unit.gyros: the sensing axes do not span three dimensions")
    models = tuple(tuple(ids.index(gid) for gid in m) for m in cfg.fdi.threecross.models)
    for i, m in enumerate(models):
        if not rank3(g[list(m)]):
            raise GeometryError(
                f"fdi.threecross.models.{i}: the axes of {''.join(ids[j] for j in m)} do not "
                "span three dimensions"
            )
    return GyroUnit(
        ids=ids,
        w=w_arr,
        u=u_arr,
        v=np.cross(w_arr, u_arr),
        nominal=nominal,
        noise=np.array(noise, dtype=float),
        models=models,
        band=cfg.fdi.threecross.band,
    )
