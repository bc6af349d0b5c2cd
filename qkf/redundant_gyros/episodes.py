r"""Calibration episodes of one gyro config, drawn fast (docs/redundant_gyros.md, "Episodes").

An episode is trial 0 of a simulation (:func:`~qkf.redundant_gyros.scenario.simulate`) seeded
with the episode's draw, restricted to what the calibration UKF sees and is judged by from
``target.start`` on: the calibrated gyro's readings, the healthy triad's rate ``ω̂_H``, the
true coefficients and the steps. :class:`EpisodeSampler` computes once per config what every
episode shares (the body rate, the faults' truth, the noise-free readings of the gyros whose
coefficients do not depend on the draw, the steps), and per draw only the noise and, with an
``onset``, the onset gyro's coefficients and readings. The result equals the simulation's
(``tests/test_gyro_batched_env.py``, ``tests/test_gyro_noise_levels.py``); the environments
and the hindsight search both draw their episodes here, so they see the same ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

import qkf.core.jit  # noqa: F401  (binds compiled callees locally: docs/performance.md)
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import fault_target, setup_for
from qkf.redundant_gyros.scenario import (
    body_rate,
    epochs,
    first_epoch,
    log_uniform,
    onset_generator,
    onset_sds,
    trial_onset,
    truth,
)


@dataclass(frozen=True)
class EpisodeInputs:
    """What one calibration episode feeds its UKF and judges it by, over the K calibrated
    epochs ``target.start …`` (internal units)."""

    z: np.ndarray  # (K,) readings of the calibrated gyro, deg/s
    rate: np.ndarray  # (K, 3) healthy-triad rate ω̂_H, deg/s
    truth: np.ndarray  # (K, 4) true [b deg/s, λ, δ_u rad, δ_v rad]
    dt: np.ndarray  # (K,) prediction step before each epoch, s
    onset_s: float | None  # the drawn onset (time of the run), s; None without an onset
    t0_s: float = 0.0  # time of the run at the first calibrated epoch, s


class EpisodeSampler:
    """The calibration episodes of ``cfg`` (module docstring): ``sampler.draw(d)`` is the
    episode of a simulation seeded with ``d``."""

    def __init__(self, cfg: GyrosConfig) -> None:
        self.cfg = cfg
        self.unit = unit = build_unit(cfg)
        sc = cfg.scenario
        self.t = t = epochs(sc.duration_s, sc.dt_s)
        self.target = fault_target(cfg, unit, t)
        self.setup = setup_for(cfg, unit, self.target)
        self.rate = body_rate(sc.body_rate, t)  # (E, 3) true body rate, deg/s
        self._truth = truth(unit, sc.faults, t)
        self._clean = unit.readings(self._truth.coeffs, self.rate)  # (E, n), shared truth
        self._sd = unit.noise * self._truth.noise_factor  # (E, n)
        specs = sc.onset_specs()  # one gyro for all of a mixture's (the config checks it)
        self._onset_gyro = unit.index(specs[0].gyro) if specs else None
        self._onset_sds = {id(o): onset_sds(o) for o in specs}
        self._sqrt_dt = np.sqrt(np.diff(t, prepend=t[0]))
        s = self.target.start
        dt = np.diff(t[max(s - 1, 0) :])
        self.dt = np.concatenate([[t[1] - t[0]], dt]) if s == 0 else dt  # (K,)

    @property
    def n_epochs(self) -> int:
        """K, the calibrated epochs of an episode."""
        return int(self.t.size - self.target.start)

    def draw(self, draw: int) -> EpisodeInputs:
        """The episode of the simulation seeded with ``draw`` (trial 0 of
        :func:`~qkf.redundant_gyros.scenario.simulate`)."""
        unit, t, s, gyro = self.unit, self.t, self.target.start, self.setup.gyro
        onset = trial_onset(self.cfg.scenario, draw, 0)  # a mixture's component's, if any
        clean, coeffs_cal, onset_s = self._clean, self._truth.coeffs[:, gyro], None
        noise_factor = 1.0
        if onset is not None and self._onset_gyro is not None:
            g = self._onset_gyro
            step_sd, walk_sd = self._onset_sds[id(onset)]
            lo, hi = onset.onset_s
            rng = onset_generator(draw, 0)
            onset_s, step, eps = _onset_numbers(rng, lo, hi, t.size)
            step = step * step_sd
            scale = log_uniform(rng, onset.drift_scale)  # draw_onset's order
            noise_factor = log_uniform(rng, onset.noise_factor)
            k_walk = 0 if onset.drift_from == "start" else first_epoch(t, onset_s)
            c = np.empty((t.size, 4))
            clean = clean.copy()
            _onset_readings(
                self._truth.coeffs[:, g], first_epoch(t, onset_s), step, eps, self._sqrt_dt,
                walk_sd, scale, k_walk, unit.w[g], unit.u[g], unit.v[g], self.rate,
                c, clean[:, g],
            )  # fmt: skip
            if g == gyro:
                coeffs_cal = c
        noise = _normals(np.random.default_rng([draw, 0]), t.size, unit.n)
        sd = self._sd
        if onset is not None and onset.noise_factor is not None and self._onset_gyro is not None:
            sd = sd.copy()
            sd[:, self._onset_gyro] = sd[:, self._onset_gyro] * noise_factor
        meas = clean - sd * noise
        for i, k0, offset in self._truth.stuck:
            meas[k0:, i] = meas[max(k0 - 1, 0), i] + offset
        rate = np.empty((t.size - s, 3))
        tri = np.array(self.setup.triad)
        _triad_rate(meas[s:], tri, unit.nominal[tri, 0], unit.nominal[tri, 1],
                    self.setup.triad_inv, rate)  # fmt: skip
        return EpisodeInputs(
            z=meas[s:, gyro],
            rate=rate,
            truth=coeffs_cal[s:],
            dt=self.dt,
            onset_s=onset_s,
            t0_s=float(t[s]),
        )


# numba's Generator draws the stream of numpy's (the same algorithms; the sampler's test holds
# the episodes to the simulation's) at about half the cost: the normals are most of a draw


@nb.njit(cache=True)
def _onset_numbers(
    rng: np.random.Generator, lo: float, hi: float, n: int
) -> tuple[float, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """draw_onset's draws, in its order: the onset time, the step's and the walk's normals."""
    return rng.uniform(lo, hi), rng.standard_normal(4), rng.standard_normal((n, 4))


@nb.njit(cache=True)
def _normals(rng: np.random.Generator, n: int, m: int) -> np.ndarray:  # pragma: no cover
    """``rng.standard_normal((n, m))``."""
    return rng.standard_normal((n, m))


@nb.njit(cache=True)
def _onset_readings(
    base: np.ndarray,
    k_on: int,
    step: np.ndarray,
    eps: np.ndarray,
    sqrt_dt: np.ndarray,
    rate_sd: np.ndarray,
    scale: float,
    k_walk: int,
    w: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    rate: np.ndarray,
    coeffs: np.ndarray,
    clean: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The onset gyro's coefficients ``coeffs`` (E, 4) and noise-free readings ``clean`` (E,):
    ``base`` plus the step from ``k_on`` on plus the walk ``Σ eps √Δt σ scale`` from after
    ``k_walk`` (as :func:`~qkf.redundant_gyros.scenario.draw_onset` and ``apply_onset``), then
    ``(1 − λ) w̄ᵀ ω − b`` (:func:`~qkf.redundant_gyros.geometry.readings`)."""
    walk = np.zeros(4)
    for k in range(base.shape[0]):
        for i in range(4):
            if k > k_walk:
                walk[i] += eps[k, i] * sqrt_dt[k] * rate_sd[i] * scale
            c = base[k, i]
            if k >= k_on:
                c += step[i]
            coeffs[k, i] = c + walk[i]
        acc = 0.0
        for j in range(3):
            acc += (w[j] - coeffs[k, 2] * u[j] - coeffs[k, 3] * v[j]) * rate[k, j]
        clean[k] = (1.0 - coeffs[k, 1]) * acc - coeffs[k, 0]


@nb.njit(cache=True)
def _triad_rate(
    meas: np.ndarray,
    triad: np.ndarray,
    bias: np.ndarray,
    scale: np.ndarray,
    tinv: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``ω̂_H = G_H⁻¹ y_H`` with ``y_H = (m + b)/(1 − λ)`` of the triad's readings
    (:func:`~qkf.redundant_gyros.ukf.triad_rate`), into ``out`` (E, 3)."""
    y = np.zeros(3)
    for k in range(meas.shape[0]):
        for j in range(3):
            y[j] = (meas[k, triad[j]] + bias[j]) / (1.0 - scale[j])
        for m in range(3):
            acc = 0.0
            for j in range(3):
                acc += tinv[m, j] * y[j]
            out[k, m] = acc


__all__ = ["EpisodeInputs", "EpisodeSampler"]
