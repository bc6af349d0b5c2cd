r"""Simulated star-camera and angular-accelerometer data with their truth (docs/sca_fusion.md,
"Simulation").

Truth attitude (body → inertial)::

    C(t) = Exp(n t e_y) · Exp(θ(t)),   θ_a(t) = Σ_j A sin(2π t / T_aj + φ_aj)

an orbit-following rotation at the orbit rate ``n`` about the body y axis with small attitude
oscillations on every axis (periods log-uniform, phases uniform, drawn from the seed). The true
rate and angular acceleration are the derivatives of the exact quaternion, taken by fourth-order
central differences with a 0.05 s step (truncation and rounding below 1e-12 rad/s²).

Measurements::

    q_sca = q ⊗ Exp(ν),                 ν ~ N(0, σ_sca²) per body axis (+ outliers)
    acc   = (ω̇ + I⁻¹(ω × Iω) + b + ε) / (1 − s),   ε ~ N(0, σ_acc²)

so that ``acc − b − s ⊙ acc − I⁻¹(ω × Iω) = ω̇ + ε`` is the estimator's model exactly. Every
random draw comes from its own child of ``SeedSequence(seed)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from qkf.core.jit import kernel_array
from qkf.core.quat import compose_rotvecs
from qkf.core.time_grid import outside_windows
from qkf.sca_fusion.config import Simulation
from qkf.sca_fusion.differentiation import euler_term, quat_conj, quat_mul

ARCSEC = np.pi / (180.0 * 3600.0)
_H = 0.05  # step of the truth's finite differences, s


@dataclass(frozen=True)
class SimulatedData:
    """Truth on the full grid and the two measured series (with their own times)."""

    t: np.ndarray  # (n,) s
    q_true: np.ndarray  # (n, 4) body → inertial, scalar last
    omega_true: np.ndarray  # (n, 3) rad/s
    omega_dot_true: np.ndarray  # (n, 3) rad/s²
    sca_t: np.ndarray  # (m,)
    sca_q: np.ndarray  # (m, 4), sign as scipy returns it (not continuous)
    acc_t: np.ndarray  # (k,)
    acc: np.ndarray  # (k, 3) rad/s²
    outlier_t: np.ndarray  # times of the star-camera outliers
    sca_sigma_rad: np.ndarray  # (3,)
    acc_sigma_rad_s2: np.ndarray  # (3,)
    acc_bias_rad_s2: np.ndarray  # (3,)
    acc_scale: np.ndarray  # (3,)


def _oscillation_params(sim: Simulation, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    osc = sim.oscillation
    shape = (3, osc.count)
    log_t = rng.uniform(np.log(osc.period_min_s), np.log(osc.period_max_s), shape)
    phase = rng.uniform(0.0, 2.0 * np.pi, shape)
    return 2.0 * np.pi / np.exp(log_t), phase


def truth_quaternion(
    t: np.ndarray, orbit_rate: float, amplitude: float, freq: np.ndarray, phase: np.ndarray
) -> np.ndarray:
    """Exact truth quaternions (…, 4) at times t (s); ``freq``/``phase`` (3, K) in rad/s, rad."""
    theta = amplitude * np.sin(t[..., None, None] * freq + phase).sum(axis=-1)  # (…, 3)
    orbit = np.zeros((*t.shape, 3))
    orbit[..., 1] = orbit_rate * t
    flat = (
        Rotation.from_rotvec(orbit.reshape(-1, 3)) * Rotation.from_rotvec(theta.reshape(-1, 3))
    ).as_quat()
    return flat.reshape(*t.shape, 4)


def truth_derivatives(
    t: np.ndarray, orbit_rate: float, amplitude: float, freq: np.ndarray, phase: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quaternion (n, 4), body rate (n, 3) and angular acceleration (n, 3) of the truth."""
    steps = np.array([-2.0, -1.0, 0.0, 1.0, 2.0]) * _H
    q = truth_quaternion(t[:, None] + steps, orbit_rate, amplitude, freq, phase)  # (n, 5, 4)
    q = q * np.sign(np.einsum("nkj,nj->nk", q, q[:, 2]))[..., None]  # one hemisphere
    qdot = (q[:, 0] - 8.0 * q[:, 1] + 8.0 * q[:, 3] - q[:, 4]) / (12.0 * _H)
    qddot = (-q[:, 0] + 16.0 * q[:, 1] - 30.0 * q[:, 2] + 16.0 * q[:, 3] - q[:, 4]) / (12.0 * _H**2)
    conj = quat_conj(q[:, 2])
    omega = 2.0 * quat_mul(conj, qdot)[:, :3]
    omega_dot = 2.0 * quat_mul(conj, qddot)[:, :3]
    return q[:, 2], omega, omega_dot


def simulate(sim: Simulation) -> SimulatedData:
    """Draw one arc (or several, if ``data_gaps`` split it) from the simulation config."""
    seeds = np.random.SeedSequence(sim.seed).spawn(4)
    rng_motion, rng_sca, rng_acc, rng_out = (np.random.default_rng(s) for s in seeds)
    n = int(np.floor(sim.duration_s / sim.dt_s + 1e-9)) + 1
    t = np.arange(n) * sim.dt_s
    freq, phase = _oscillation_params(sim, rng_motion)
    orbit_rate = 2.0 * np.pi / sim.orbit_period_s
    amp = sim.oscillation.amplitude_urad * 1e-6
    q, omega, omega_dot = truth_derivatives(t, orbit_rate, amp, freq, phase)

    sca_sigma = np.asarray(sim.sca_noise_arcsec) * ARCSEC
    nu = rng_sca.standard_normal((n, 3)) * sca_sigma
    n_out = round(sim.sca_outliers.fraction * n)
    out_idx = np.sort(rng_out.choice(n, size=n_out, replace=False)) if n_out else np.zeros(0, int)
    signs = rng_out.choice([-1.0, 1.0], size=(n_out, 3))
    nu[out_idx] += sim.sca_outliers.size_sigma * sca_sigma * signs
    q_sca = np.empty_like(q)
    q_rows = kernel_array(q, float, q.shape)  # one compiled copy (qkf.core.jit.kernel_array)
    compose_rotvecs(q_rows, nu, q_sca)  # q ⊗ Exp(ν), bit for bit scipy's composition

    acc_sigma = np.asarray(sim.acc_noise_rad_s2)
    bias = np.asarray(sim.acc_bias_rad_s2)
    scale = np.asarray(sim.acc_scale)
    eps = rng_acc.standard_normal((n, 3)) * acc_sigma
    gyro = euler_term(omega, np.asarray(sim.proof_mass_inertia))
    acc = (omega_dot + gyro + bias + eps) / (1.0 - scale)

    data_keep = outside_windows(t, [(w.start_s, w.end_s) for w in sim.data_gaps])
    sca_keep = data_keep & outside_windows(t, [(w.start_s, w.end_s) for w in sim.sca_gaps])
    out_mask = np.zeros(n, dtype=bool)
    out_mask[out_idx] = True
    return SimulatedData(
        t=t,
        q_true=q,
        omega_true=omega,
        omega_dot_true=omega_dot,
        sca_t=t[sca_keep],
        sca_q=q_sca[sca_keep],
        acc_t=t[data_keep],
        acc=acc[data_keep],
        outlier_t=t[out_mask & sca_keep],
        sca_sigma_rad=sca_sigma,
        acc_sigma_rad_s2=acc_sigma,
        acc_bias_rad_s2=bias,
        acc_scale=scale,
    )
