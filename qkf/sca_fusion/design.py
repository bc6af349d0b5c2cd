r"""Observation equations of one arc (docs/sca_fusion.md, "Observation equations").

Parameters, axis-major so that the band of the normal matrix is as narrow as the
differentiation window (the design couples an axis only with itself)::

    dx[a·n + i]      small body-frame rotation of epoch i about axis a (rad): C = Ĉ Exp(dx_i)
    dx[3n + …]       accelerometer bias (rad/s²) per interval and axis, then scale per interval
                     and axis (border)

Star camera, epoch i (3 rows)::   Log(q̂_i⁻¹ ⊗ q_sca,i) = dx_i

Accelerometer, epoch i (3 rows), with window s_i and weights f_ik of the second derivative::

    acc_i − b − s ⊙ acc_i − I⁻¹(ω̂_i × I ω̂_i) − 2 vec(q̂_i* ⊗ Σ_k f_ik q̂_{s_i+k})
        = Σ_k f_ik dx_{s_i+k} + Δb + diag(acc_i) Δs

(the design ``A_k = f_k I₃``, as GROOPS). Epochs without a star-camera observation get a weak
prior on their step (``1/σ²`` added to N, nothing to n).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from qkf.core.least_squares import Linearization, ObservationGroup
from qkf.sca_fusion.config import AccCalibration, Estimator
from qkf.sca_fusion.data import ArcData
from qkf.sca_fusion.differentiation import (
    body_rate,
    derivative_weights,
    euler_term,
    quat_conj,
    quat_exp,
    quat_log,
    quat_mul,
    windowed_sum,
)

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class CalibrationLayout:
    """Border parameters of an arc: interval index of every epoch for bias and scale, and the
    parameter names (``acc_bias_x``, or ``acc_bias_x_i<k>`` with several intervals)."""

    bias_interval: np.ndarray | None  # (n,) or None when not estimated
    scale_interval: np.ndarray | None
    n_bias: int
    n_scale: int
    names: tuple[str, ...]
    interval_start_s: tuple[float, ...]

    @property
    def size(self) -> int:
        return 3 * (self.n_bias + self.n_scale)


def _intervals(
    t: np.ndarray, has_acc: np.ndarray, cal: AccCalibration
) -> tuple[np.ndarray | None, int]:
    """Interval index of every epoch; intervals without an accelerometer epoch are dropped
    (their parameters would be undetermined)."""
    if not cal.estimate:
        return None, 0
    if cal.interval_s is None:
        return np.zeros(t.size, dtype=np.int64), 1
    raw = np.floor((t - t[0]) / cal.interval_s + 1e-9).astype(np.int64)
    used = np.unique(raw[has_acc]) if has_acc.any() else np.zeros(1, dtype=np.int64)
    k = np.clip(np.searchsorted(used, raw), 0, used.size - 1)
    return k, int(used.size)


def calibration_layout(t: np.ndarray, est: Estimator, has_acc: np.ndarray) -> CalibrationLayout:
    """Bias and scale parameters of an arc with epochs ``t`` (accelerometer where
    ``has_acc``)."""
    bias, nb = _intervals(t, has_acc, est.acc_bias)
    scale, ns = _intervals(t, has_acc, est.acc_scale)
    names: list[str] = []
    starts: list[float] = []
    for kind, idx, count in (("acc_bias", bias, nb), ("acc_scale", scale, ns)):
        for k in range(count):
            t0 = float(t[np.argmax((idx == k) & has_acc)]) if idx is not None else float(t[0])
            for a in AXES:
                names.append(f"{kind}_{a}" + (f"_i{k}" if count > 1 else ""))
                starts.append(t0)
    return CalibrationLayout(bias, scale, nb, ns, tuple(names), tuple(starts))


@dataclass(frozen=True)
class ArcModel:
    """What stays fixed over the iterations of one arc: the layout, the differentiation
    windows and the two design matrices (the design does not depend on the Taylor point)."""

    arc: ArcData
    est: Estimator
    layout: CalibrationLayout
    start: np.ndarray  # differentiation window start (n,)
    weights: np.ndarray  # second-derivative weights (n, d + 1), 1/s²
    sca_epochs: np.ndarray  # arc epochs with a star camera (m,)
    acc_epochs: np.ndarray  # arc epochs with an accelerometer (k,)
    sca_design: sp.csr_matrix  # (3m, u)
    acc_design: sp.csr_matrix  # (3k, u)
    prior: np.ndarray  # (u,) weak-prior weights on the step, 1/rad²

    @property
    def n_params(self) -> int:
        return 3 * self.arc.n + self.layout.size


def arc_model(arc: ArcData, est: Estimator) -> ArcModel:
    """Build the fixed part of an arc's observation equations."""
    n = arc.n
    nb = 3 * n
    start, weights = derivative_weights(n, est.interpolation_degree, 2, arc.dt)
    lay = calibration_layout(arc.t, est, arc.has_acc)
    u = nb + lay.size

    e_sca = np.flatnonzero(arc.has_sca)
    m = e_sca.size
    axis = np.tile(np.arange(3), m)
    cols = axis * n + np.repeat(e_sca, 3)
    a_sca = sp.csr_matrix((np.ones(3 * m), (np.arange(3 * m), cols)), shape=(3 * m, u))

    e_acc = np.flatnonzero(arc.has_acc)
    k = e_acc.size
    d1 = weights.shape[1]
    axis = np.tile(np.arange(3), k)
    epoch = np.repeat(e_acc, 3)
    rows = [np.repeat(np.arange(3 * k), d1)]
    cols_l = [(axis[:, None] * n + start[epoch][:, None] + np.arange(d1)[None, :]).ravel()]
    vals = [weights[epoch].ravel()]  # A_k = f_k I₃
    if lay.bias_interval is not None:
        rows.append(np.arange(3 * k))
        cols_l.append(nb + 3 * lay.bias_interval[epoch] + axis)
        vals.append(np.ones(3 * k))
    if lay.scale_interval is not None:
        rows.append(np.arange(3 * k))
        cols_l.append(nb + 3 * lay.n_bias + 3 * lay.scale_interval[epoch] + axis)
        vals.append(arc.acc[e_acc].ravel())
    a_acc = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols_l))), shape=(3 * k, u)
    )

    prior = np.zeros(u)
    no_sca = np.flatnonzero(~arc.has_sca)
    for a in range(3):
        prior[a * n + no_sca] = 1.0 / np.deg2rad(est.weak_prior_deg) ** 2
    return ArcModel(arc, est, lay, start, weights, e_sca, e_acc, a_sca, a_acc, prior)


def calibration_effect(model: ArcModel, x_cal: np.ndarray) -> np.ndarray:
    """``b(t) + s(t) ⊙ acc`` (n, 3) for calibration parameters ``x_cal`` (rad/s², scale)."""
    lay, arc = model.layout, model.arc
    out = np.zeros((arc.n, 3))
    acc = np.nan_to_num(arc.acc)
    if lay.bias_interval is not None:
        out += x_cal[: 3 * lay.n_bias].reshape(lay.n_bias, 3)[lay.bias_interval]
    if lay.scale_interval is not None:
        s = x_cal[3 * lay.n_bias :].reshape(lay.n_scale, 3)[lay.scale_interval]
        out += s * acc
    return out


def modelled_acceleration(model: ArcModel, q: np.ndarray) -> np.ndarray:
    """What the instrument should read at the Taylor point q (n, 4), before calibration:
    ``2 vec(q* ⊗ q̈) + I⁻¹(ω × Iω)`` (the last term only with the Euler correction)."""
    qdd = windowed_sum(q, model.start, model.weights)
    wdot = 2.0 * quat_mul(quat_conj(q), qdd)[:, :3]
    eul = model.est.euler_correction
    if eul.enabled:
        omega = body_rate(q, model.arc.dt, model.est.interpolation_degree)
        wdot = wdot + euler_term(omega, np.asarray(eul.proof_mass_inertia))
    return wdot


def sca_residual(q_taylor: np.ndarray, q_sca: np.ndarray) -> np.ndarray:
    """``Log(q̂⁻¹ ⊗ q_sca)`` (m, 3), rad, body frame."""
    return quat_log(quat_mul(quat_conj(q_taylor), q_sca))


def linearize(model: ArcModel, q: np.ndarray, x_cal: np.ndarray) -> Linearization:
    """The observation groups ``sca`` and ``acc`` and the weak prior at Taylor point q."""
    arc, est = model.arc, model.est
    groups = []
    e_sca = model.sca_epochs
    m3 = 3 * e_sca.size
    per_axis = np.tile(np.arange(3), e_sca.size)
    groups.append(
        ObservationGroup(
            name="sca",
            design=model.sca_design,
            residual=sca_residual(q[e_sca], arc.sca_q[e_sca]).ravel(),
            sigma=np.full(m3, est.sigma_star_camera_rad),
            component=per_axis if est.estimate_sigma_sca_per_axis else np.zeros(m3, np.int64),
            epoch=np.repeat(e_sca, 3),
            component_names=AXES if est.estimate_sigma_sca_per_axis else ("all",),
        )
    )
    e_acc = model.acc_epochs
    if e_acc.size:
        k3 = 3 * e_acc.size
        per_axis = np.tile(np.arange(3), e_acc.size)
        predicted = modelled_acceleration(model, q) + calibration_effect(model, x_cal)
        groups.append(
            ObservationGroup(
                name="acc",
                design=model.acc_design,
                residual=(arc.acc[e_acc] - predicted[e_acc]).ravel(),
                sigma=np.asarray(est.sigma_accelerometer_rad_s2)[per_axis],
                component=per_axis if est.estimate_sigma_acc_per_axis else np.zeros(k3, np.int64),
                epoch=np.repeat(e_acc, 3),
                component_names=AXES if est.estimate_sigma_acc_per_axis else ("all",),
            )
        )
    return Linearization(groups, model.n_params, n_band=3 * arc.n, prior_normal=model.prior)


def apply_step(q: np.ndarray, dx: np.ndarray, n: int) -> np.ndarray:
    """``q ⊗ Exp(dx_i)`` for every epoch (stays sign-continuous: the steps are small)."""
    step = np.stack([dx[:n], dx[n : 2 * n], dx[2 * n : 3 * n]], axis=1)
    new = quat_mul(q, quat_exp(step))
    return new / np.linalg.norm(new, axis=1, keepdims=True)
