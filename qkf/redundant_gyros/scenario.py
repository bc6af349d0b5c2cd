r"""Truth simulation of a redundant gyro unit, vectorised over trials (docs/redundant_gyros.md,
"Scenario").

The body rate and the faults are the same in every trial; only the white noise differs. Trial
``k`` of a run with seed ``s`` draws its noise from ``default_rng([s, k])``, so it is the same
whatever batch or chunk it is simulated in, and the same for every fault a benchmark injects
(common random numbers). Readings (deg/s)::

    m_i(t) = (1 − λ_i(t)) w̄_i(t)ᵀ ω(t) − b_i(t) − σ_i(t) ε_i(t),   ε ~ N(0, 1)

with the coefficients of gyro i changed by its faults from their time on; a stuck gyro repeats
its last healthy reading (plus ``size``).

A scenario with an ``onset`` (:class:`~qkf.redundant_gyros.config.OnsetDrift`;
docs/redundant_gyros.md, "Onset and drift") also draws, per trial, the onset time, a step of
the onset gyro's coefficients at that time and a random walk of them, from
``default_rng([s, k, ONSET_STREAM])``: a stream of its own, so the noise of trial ``k`` is the
same with the option on or off, and a scenario without it is simulated exactly as before. The
truth then differs between trials: ``GyroData.coeffs`` is (B, E, n, 4) instead of (E, n, 4).

A scenario with an ``onset_mixture`` first draws each trial's component, uniformly, from
``default_rng([s, k, MIXTURE_STREAM])`` (:func:`trial_onset`), then that component's onset as
above (a component without one: constant coefficients, ``onset_s`` NaN).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from qkf.core.units import DEG
from qkf.redundant_gyros.config import BodyRate, Fault, OnsetDrift, Scenario
from qkf.redundant_gyros.geometry import GyroUnit


@dataclass(frozen=True)
class GyroData:
    """Readings of B trials over E epochs (simulated, or recorded with ``rate``/``coeffs`` None)."""

    t: np.ndarray  # (E,) s
    meas: np.ndarray  # (B, E, n) deg/s
    rate: np.ndarray | None  # (E, 3) true body rate, deg/s
    # (E, n, 4) true coefficients [b deg/s, λ, δ_u rad, δ_v rad]; (B, E, n, 4) with an onset
    coeffs: np.ndarray | None
    onset_s: np.ndarray | None = None  # (B,) drawn onset times, s (an onset scenario only)

    def trial_coeffs(self, row: int = 0) -> np.ndarray | None:
        """The true coefficients (E, n, 4) of trial ``row`` (shared or per trial)."""
        if self.coeffs is None:
            return None
        return self.coeffs if self.coeffs.ndim == 3 else self.coeffs[row]

    @property
    def n_epochs(self) -> int:
        return int(self.t.size)

    @property
    def n_trials(self) -> int:
        return int(self.meas.shape[0])


def epochs(duration_s: float, dt_s: float) -> np.ndarray:
    """Epoch times ``0, dt, …`` up to ``duration_s`` (exclusive), s."""
    n = max(2, math.floor(duration_s / dt_s + 1e-9))
    return np.arange(n) * dt_s


def first_epoch(t: np.ndarray, t_s: float) -> int:
    """Index of the first epoch at or after ``t_s``."""
    return int(np.searchsorted(t, t_s - 1e-9 * max(1.0, abs(t_s))))


def body_rate(profile: BodyRate, t: np.ndarray) -> np.ndarray:
    """``c + A sin(2π t / T + φ)`` per axis, deg/s; (E, 3)."""
    c = np.asarray(profile.constant_deg_s)
    a = np.asarray(profile.amplitude_deg_s)
    period = np.asarray(profile.period_s)
    phase = np.asarray(profile.phase_deg) * DEG
    return c + a * np.sin(2.0 * np.pi * t[:, None] / period + phase)


@dataclass(frozen=True)
class Truth:
    coeffs: np.ndarray  # (E, n, 4)
    noise_factor: np.ndarray  # (E, n) multiplies σ_i
    stuck: tuple[tuple[int, int, float], ...]  # (gyro, first stuck epoch, offset deg/s)


def truth(unit: GyroUnit, faults: Sequence[Fault], t: np.ndarray) -> Truth:
    """The true coefficients per epoch: the nominal ones changed by the faults."""
    coeffs = np.broadcast_to(unit.nominal, (t.size, unit.n, 4)).copy()
    factor = np.ones((t.size, unit.n))
    stuck = []
    for f in faults:
        i, k0 = unit.index(f.gyro), first_epoch(t, f.t_s)
        after = slice(k0, None)
        if isinstance(f.size, tuple):  # misalignment_step (the schema allows pairs only there)
            coeffs[after, i, 2] += f.size[0] * DEG
            coeffs[after, i, 3] += f.size[1] * DEG
            continue
        size = float(f.size)
        if f.kind == "bias_step":
            coeffs[after, i, 0] += size
        elif f.kind == "bias_ramp":
            coeffs[after, i, 0] += size * (t[after] - f.t_s)
        elif f.kind == "scale_step":
            coeffs[after, i, 1] += size
        elif f.kind == "noise_increase":
            factor[after, i] *= size
        elif f.kind == "stuck":
            stuck.append((i, k0, size))
        else:  # pragma: no cover - the schema admits no other kind
            raise ValueError(f"fault kind {f.kind!r} with size {f.size!r}")
    return Truth(coeffs, factor, tuple(stuck))


ONSET_STREAM = 0x0115E7
"""Third word of the seed of a trial's onset draws (its noise has two words)."""
MIXTURE_STREAM = 0x3117C5
"""Third word of the seed of a trial's onset-mixture component (a stream apart from the onset's,
so a component draws the onset it draws as a preset of its own)."""


def mixture_component(scenario: Scenario, seed: int, trial: int) -> int | None:
    """Index of the ``onset_mixture`` component trial ``trial`` of seed ``seed`` draws (uniform,
    from ``default_rng([seed, trial, MIXTURE_STREAM])``); None without a mixture."""
    if scenario.onset_mixture is None:
        return None
    rng = np.random.default_rng([seed, int(trial), MIXTURE_STREAM])
    return int(rng.integers(len(scenario.onset_mixture)))


def trial_onset(scenario: Scenario, seed: int, trial: int) -> OnsetDrift | None:
    """The onset trial ``trial`` of seed ``seed`` draws: ``scenario.onset``, or that of its
    mixture component (:func:`mixture_component`)."""
    i = mixture_component(scenario, seed, trial)
    if i is None:
        return scenario.onset
    assert scenario.onset_mixture is not None
    return scenario.onset_mixture[i].onset


def onset_generator(seed: int, trial: int) -> np.random.Generator:
    """The generator of trial ``trial``'s onset, step and walk: ``default_rng([seed, trial,
    ONSET_STREAM])``, independent of its noise."""
    return np.random.default_rng([seed, int(trial), ONSET_STREAM])


@dataclass(frozen=True)
class OnsetDraw:
    """One trial's draw of an :class:`OnsetDrift` (internal units: b deg/s, λ, δ rad)."""

    onset_s: float  # s; at or after the end of the run: no step
    step: np.ndarray  # (4,) added to the coefficients from the onset's first epoch on
    walk: np.ndarray  # (E, 4) random-walk offset per epoch (0 before its start)
    drift_scale: float = 1.0  # the factor drawn on the drift rates (1: none drawn)
    noise_factor: float = 1.0  # the factor drawn on the gyro's white-noise sd (1: none drawn)


def log_uniform(rng: np.random.Generator, bounds: tuple[float, float] | None) -> float:
    """A log-uniform draw in ``bounds``; 1.0 and no draw for ``None``."""
    if bounds is None:
        return 1.0
    return float(np.exp(rng.uniform(np.log(bounds[0]), np.log(bounds[1]))))


def onset_sds(spec: OnsetDrift) -> tuple[np.ndarray, np.ndarray]:
    """The step's sd and the walk's sd per √s of ``[b, λ, δ_u, δ_v]`` (internal units)."""
    st, dr = spec.step, spec.drift
    step_sd = np.array([st.bias_deg_s, st.scale, st.delta_u_deg * DEG, st.delta_v_deg * DEG])
    rate_sd = np.array(
        [
            dr.bias_deg_s_per_sqrt_s,
            dr.scale_per_sqrt_s,
            dr.delta_u_deg_per_sqrt_s * DEG,
            dr.delta_v_deg_per_sqrt_s * DEG,
        ]
    )
    return step_sd, rate_sd


def draw_onset(spec: OnsetDrift, t: np.ndarray, rng: np.random.Generator) -> OnsetDraw:
    """Draw the onset time ``U(onset_s)``, the step ``N(0, diag(step²))`` and the walk: from its
    first epoch ``k₀`` (the onset's, or 0 with ``drift_from: start``) on, increments
    ``N(0, σ² Δt_k)``, so the offset at epoch k has variance ``σ² (t_k − t_{k₀})``. The draws
    are taken in this fixed order whatever the sds, so a sd of 0 leaves the others unchanged.
    Then, only if the spec asks for them, the noise levels: the drift scale (log-uniform, it
    multiplies the walk's increments) and the white-noise factor; a spec without them draws
    exactly what it drew before they existed."""
    lo, hi = spec.onset_s
    onset = float(rng.uniform(lo, hi))
    step_sd, rate_sd = onset_sds(spec)
    step = rng.standard_normal(4) * step_sd
    eps = rng.standard_normal((t.size, 4))
    scale = log_uniform(rng, spec.drift_scale)
    noise = log_uniform(rng, spec.noise_factor)
    k0 = 0 if spec.drift_from == "start" else first_epoch(t, onset)
    inc = eps * np.sqrt(np.diff(t, prepend=t[0]))[:, None] * rate_sd * scale
    inc[: k0 + 1] = 0.0  # the walk is 0 at its first epoch
    return OnsetDraw(onset, step, np.cumsum(inc, axis=0), scale, noise)


def apply_onset(coeffs: np.ndarray, gyro: int, draw: OnsetDraw, t: np.ndarray) -> np.ndarray:
    """``coeffs`` (E, n, 4) with gyro ``gyro``'s step (from the onset on) and walk added."""
    out = coeffs.copy()
    out[first_epoch(t, draw.onset_s) :, gyro] += draw.step
    out[:, gyro] += draw.walk
    return out


def trial_noise(
    seed: int, trial_ids: Sequence[int] | np.ndarray, n_epochs: int, n: int
) -> np.ndarray:
    """Standard normal draws (B, E, n), trial k from ``default_rng([seed, k])``."""
    out = np.empty((len(trial_ids), n_epochs, n))
    for row, k in enumerate(trial_ids):
        out[row] = np.random.default_rng([seed, int(k)]).standard_normal((n_epochs, n))
    return out


def simulate(
    unit: GyroUnit,
    profile: BodyRate,
    faults: Sequence[Fault],
    t: np.ndarray,
    seed: int,
    trial_ids: Sequence[int] | np.ndarray,
    onset: OnsetDrift | None = None,
    onsets: Sequence[OnsetDrift | None] | None = None,
) -> GyroData:
    """Readings of the trials ``trial_ids`` (see the module docstring); ``onset`` draws each
    trial's onset, step and walk (then ``coeffs`` is per trial, (B, E, n, 4)); ``onsets``, one
    per trial (an onset mixture: :func:`trial_onset`), replaces it."""
    rate = body_rate(profile, t)
    tr = truth(unit, faults, t)
    if onsets is None and onset is not None:  # the same onset law in every trial
        onsets = [onset] * len(trial_ids)
    if onsets is not None:
        return _simulate_onsets(unit, tr, rate, t, seed, trial_ids, list(onsets))
    clean = unit.readings(tr.coeffs, rate)  # (E, n): the truth every trial shares
    sd = unit.noise * tr.noise_factor  # (E, n)
    meas = _measured(clean, sd, tr, seed, trial_ids, t.size, unit.n)
    return GyroData(t=t, meas=meas, rate=rate, coeffs=tr.coeffs, onset_s=None)


def _simulate_onsets(
    unit: GyroUnit,
    tr: Truth,
    rate: np.ndarray,
    t: np.ndarray,
    seed: int,
    trial_ids: Sequence[int] | np.ndarray,
    specs: list[OnsetDrift | None],
) -> GyroData:
    """:func:`simulate` with each trial's own onset spec (None: none): its onset, step and walk
    from the trial's onset stream (:func:`draw_onset`), its white noise scaled by the drawn
    factor; ``coeffs`` is per trial, (B, E, n, 4)."""
    if len(specs) != len(trial_ids):
        raise ValueError(f"{len(specs)} onsets for {len(trial_ids)} trials")
    draws = [
        None if s is None else draw_onset(s, t, onset_generator(seed, int(k)))
        for s, k in zip(specs, trial_ids, strict=True)
    ]
    per_trial = zip(specs, draws, strict=True)
    coeffs = np.stack(
        [tr.coeffs if s is None or d is None else apply_onset(tr.coeffs, unit.index(s.gyro), d, t)
         for s, d in per_trial]
    )  # fmt: skip
    onset_s = np.array([math.nan if d is None else d.onset_s for d in draws])
    clean = unit.readings(coeffs, rate)
    sd = np.broadcast_to(unit.noise * tr.noise_factor, (len(specs), t.size, unit.n)).copy()
    for row, (s, d) in enumerate(zip(specs, draws, strict=True)):
        if s is not None and d is not None and s.noise_factor is not None:
            g = unit.index(s.gyro)
            sd[row, :, g] = sd[row, :, g] * d.noise_factor
    meas = _measured(clean, sd, tr, seed, trial_ids, t.size, unit.n)
    return GyroData(t=t, meas=meas, rate=rate, coeffs=coeffs, onset_s=onset_s)


def _measured(
    clean: np.ndarray,
    sd: np.ndarray,
    tr: Truth,
    seed: int,
    trial_ids: Sequence[int] | np.ndarray,
    n_epochs: int,
    n: int,
) -> np.ndarray:
    """Readings (B, E, n): ``clean − sd · ε`` with the trials' noise, then the stuck gyros held."""
    meas = clean - sd * trial_noise(seed, trial_ids, n_epochs, n)
    for i, k0, offset in tr.stuck:
        held = meas[:, max(k0 - 1, 0), i] + offset
        meas[:, k0:, i] = held[:, None]
    return meas
