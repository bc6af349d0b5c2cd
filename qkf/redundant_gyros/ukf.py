r"""UKF calibration of an isolated gyro (docs/redundant_gyros.md, "UKF").

State of the isolated gyro j, a random walk: ``x = [b (deg/s), λ, δ_u (rad), δ_v (rad)]``,
``x_{k+1} = x_k + w_k``, ``w_k ~ N(0, κ diag(q²) Δt_k)``.

Measurement: the parity (left-null-space) combination of a healthy triad H and gyro j. With
``G_H`` the triad's compensated geometry (rows ``w̄_h``, invertible) and ``a(x) = (1 − λ) w̄(x)``,
``w̄(x) = w − δ_u u − δ_v v``, the vector ``n = [−G_H⁻ᵀ a(x); 1]`` spans the left null space of
``[G_H; a(x)ᵀ]``; applied to ``[y_H; m_j + b]`` it gives, normalised so that gyro j's weight is 1,

    m_j = h(x) + ν,   h(x) = (1 − λ) w̄(x)ᵀ ω̂_H − b,   ω̂_H = G_H⁻¹ y_H,
    R(x) = σ_j² + ‖(1 − λ) w̄(x)ᵀ G_H⁻¹ diag(s_H)‖²,

with ``y_H`` the triad's compensated readings and ``s_H`` their noise sd. The body rate never
enters: only readings do. ``R`` is evaluated at the predicted state each step. The filter is
filterpy's ``UnscentedKalmanFilter`` with ``MerweScaledSigmaPoints``; its update is the
standard ``P − K S Kᵀ``, symmetrised here after every step.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from qkf.core.units import DEG
from qkf.redundant_gyros.config import CalibrationConfig
from qkf.redundant_gyros.geometry import GyroUnit

DIM = 4
DISPLAY_SCALE = np.array([1.0, 1.0, DEG, DEG])
"""Internal value / display value per state: b deg/s, λ, δ_u and δ_v in deg at the edges."""


@dataclass(frozen=True)
class UkfSetup:
    """Everything the calibration of one gyro needs, in internal units."""

    gyro: int
    triad: tuple[int, int, int]
    w: np.ndarray  # (3,) design axes of the calibrated gyro
    u: np.ndarray
    v: np.ndarray
    triad_inv: np.ndarray  # (3, 3) G_H⁻¹
    triad_noise: np.ndarray  # (3,) compensated noise sd of the triad, deg/s
    noise: float  # raw noise sd of the calibrated gyro, deg/s
    x0: np.ndarray  # (4,) prior mean: the gyro's nominal coefficients
    p0_sd: np.ndarray  # (4,) prior sd
    q_sd: np.ndarray  # (4,) random-walk intensity per √s (κ = 1)
    alpha: float
    beta: float
    kappa_points: float


def best_triad(unit: GyroUnit, gyro: int) -> tuple[int, int, int]:
    """The three other gyros whose compensated axes are best conditioned (largest |det|)."""
    others = [i for i in range(unit.n) if i != gyro]
    best = max(combinations(others, 3), key=lambda c: abs(np.linalg.det(unit.g[list(c)])))
    return (best[0], best[1], best[2])


def make_setup(
    unit: GyroUnit, cal: CalibrationConfig, gyro: int, triad: tuple[int, int, int] | None = None
) -> UkfSetup:
    """Calibration of ``gyro`` against ``triad`` (default: :func:`best_triad`)."""
    tri = triad if triad is not None else best_triad(unit, gyro)
    if gyro in tri:
        raise ValueError("the triad must not contain the calibrated gyro")
    g_h = unit.g[list(tri)]
    if abs(np.linalg.det(g_h)) < 1e-9:
        raise ValueError(f"triad {''.join(unit.ids[i] for i in tri)} is degenerate")
    sig, pn = cal.initial_sigma, cal.process_noise
    sp = cal.sigma_points
    return UkfSetup(
        gyro=gyro,
        triad=tri,
        w=unit.w[gyro],
        u=unit.u[gyro],
        v=unit.v[gyro],
        triad_inv=np.linalg.inv(g_h),  # 3 × 3, well conditioned by construction
        triad_noise=unit.comp_noise[list(tri)],
        noise=float(unit.noise[gyro]),
        x0=unit.nominal[gyro].copy(),
        p0_sd=np.array([sig.bias_deg_s, sig.scale, sig.delta_deg * DEG, sig.delta_deg * DEG]),
        q_sd=np.array(
            [
                pn.bias_deg_s_per_sqrt_s,
                pn.scale_per_sqrt_s,
                pn.delta_deg_per_sqrt_s * DEG,
                pn.delta_deg_per_sqrt_s * DEG,
            ]
        ),
        alpha=sp.alpha,
        beta=sp.beta,
        kappa_points=3.0 - DIM if sp.kappa is None else sp.kappa,
    )


def triad_rate(unit: GyroUnit, setup: UkfSetup, meas: np.ndarray) -> np.ndarray:
    """``ω̂_H = G_H⁻¹ y_H`` from raw readings ``meas`` (..., n): (..., 3) deg/s."""
    y = unit.compensate(meas)[..., list(setup.triad)]
    return np.asarray(y @ setup.triad_inv.T)


def axis_gain(setup: UkfSetup, x: np.ndarray) -> np.ndarray:
    """``a(x) = (1 − λ) w̄(x)``, the calibrated gyro's effective axis (3,)."""
    return (1.0 - x[1]) * (setup.w - x[2] * setup.u - x[3] * setup.v)


def measurement(x: np.ndarray, rate: np.ndarray, setup: UkfSetup) -> np.ndarray:
    """``h(x) = (1 − λ) w̄(x)ᵀ ω̂_H − b`` (deg/s), as a length-1 array."""
    return np.array([axis_gain(setup, x) @ rate - x[0]])


def measurement_variance(setup: UkfSetup, x: np.ndarray) -> float:
    """``R(x) = σ_j² + ‖a(x)ᵀ G_H⁻¹ diag(s_H)‖²`` (deg/s)²."""
    through = (axis_gain(setup, x) @ setup.triad_inv) * setup.triad_noise
    return float(setup.noise**2 + through @ through)


def _identity(x: np.ndarray, dt: float) -> np.ndarray:
    return x


@dataclass
class StepResult:
    innovation: float
    variance: float  # S, (deg/s)²
    ok: bool


class CalibrationUKF:
    """One filterpy UKF over the calibrated gyro's coefficients (see the module docstring)."""

    def __init__(self, setup: UkfSetup, dt: float) -> None:
        self.setup = setup
        points = MerweScaledSigmaPoints(
            DIM, alpha=setup.alpha, beta=setup.beta, kappa=setup.kappa_points
        )
        self.kf = UnscentedKalmanFilter(
            dim_x=DIM, dim_z=1, dt=dt, hx=measurement, fx=_identity, points=points
        )
        self.kf.x = setup.x0.copy()
        self.kf.P = np.diag(setup.p0_sd**2)
        self.q_unit = np.diag(setup.q_sd**2)
        self.diverged = False

    @property
    def x(self) -> np.ndarray:
        return np.asarray(self.kf.x)

    @property
    def P(self) -> np.ndarray:
        return np.asarray(self.kf.P)

    def load(self, x: np.ndarray, p: np.ndarray, diverged: bool = False) -> None:
        """Set the state (to run a copy of another filter from where it stands)."""
        self.kf.x = x.copy()
        self.kf.P = p.copy()
        self.diverged = diverged

    def step(self, z: float, rate: np.ndarray, dt: float, kappa: float = 1.0) -> StepResult:
        """Predict over ``dt`` with ``Q = κ diag(q²) dt``, then update with reading ``z`` of the
        calibrated gyro and the triad rate ``rate`` (deg/s)."""
        if self.diverged:
            return StepResult(np.nan, np.nan, False)
        try:
            self.kf.Q = kappa * dt * self.q_unit
            self.kf.predict(dt=dt)
            r = measurement_variance(self.setup, self.kf.x)
            self.kf.update(np.array([z]), R=np.array([[r]]), rate=rate, setup=self.setup)
            self.kf.P = 0.5 * (self.kf.P + self.kf.P.T)
        except (np.linalg.LinAlgError, ValueError):
            self.diverged = True
            return StepResult(np.nan, np.nan, False)
        nu, s = float(self.kf.y[0]), float(self.kf.S[0, 0])
        ok = bool(np.all(np.isfinite(self.kf.x)) and np.all(np.isfinite(self.kf.P)) and s > 0)
        if not ok:
            self.diverged = True
        return StepResult(nu, s, ok)


def log_likelihood(innovation: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """``−½ (ν² / S + log S)`` per step (the constant dropped)."""
    return -0.5 * (innovation**2 / variance + np.log(variance))


@dataclass(frozen=True)
class CalibrationRecord:
    """The calibration of one gyro over its epochs (internal units)."""

    setup: UkfSetup
    t: np.ndarray  # (K,) s
    x: np.ndarray  # (K, 4) posterior estimates
    cov: np.ndarray  # (K, 4, 4)
    innovation: np.ndarray  # (K,)
    variance: np.ndarray  # (K,)
    diverged: bool

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.einsum("kii->ki", self.cov))


def calibrate(
    unit: GyroUnit,
    setup: UkfSetup,
    t: np.ndarray,
    meas: np.ndarray,
    start: int = 0,
    kappa: float = 1.0,
) -> CalibrationRecord:
    """Run the UKF over epochs ``start …`` of one trial's readings ``meas`` (E, n), deg/s."""
    rates = triad_rate(unit, setup, meas[start:])
    z = meas[start:, setup.gyro]
    times = t[start:]
    k = times.size
    dts = np.diff(t[start - 1 : start + k]) if start > 0 else np.diff(times, prepend=times[0])
    if start == 0 and k > 1:
        dts[0] = times[1] - times[0]
    ukf = CalibrationUKF(setup, float(dts[0]))
    x = np.full((k, DIM), np.nan)
    cov = np.full((k, DIM, DIM), np.nan)
    nu = np.full(k, np.nan)
    var = np.full(k, np.nan)
    for i in range(k):
        res = ukf.step(float(z[i]), rates[i], float(dts[i]), kappa)
        if not res.ok:
            break
        x[i], cov[i], nu[i], var[i] = ukf.kf.x, ukf.kf.P, res.innovation, res.variance
    return CalibrationRecord(setup, times, x, cov, nu, var, ukf.diverged)
