r"""Truth simulation of the transfer-alignment scenario (docs/models.md), vectorised over trials.

Per epoch ``t_k = k Δt`` (k = 0 … N−1)::

    ω_k   = (0, −n, 0) + manoeuvre rates                 (deterministic, body frame, rad/s)
    C_{k+1} = C_k Exp(ω_k Δt)                              (C: body → inertial, C_0 = I)
    b_{k+1} = b_k + N(0, σ_u² Δt)                          (rad/s)
    p_{k+1} = p_k + N(0, σ_p(t_k)² Δt) + jumps             (dimensionless)
    ω̃_k   = (I + K(p_k)) ω_k + b_k + N(0, σ_v²/Δt)       (gyro, rad/s)
    C_ADS,k = C_k Exp(N(0, σ_a² I)),   ω_ADS,k = ω_k + N(0, σ_r² I)

A randomized family (``scenario.random_events``) draws each trial's manoeuvres, jumps, drift
transient and true σ_a (:func:`draw_events`), or first one family of a mixture
(:func:`draw_trial`); docs/models.md, "Scenario families".

Randomness: trial ``i`` of a run with seed ``s`` draws from
``numpy.random.SeedSequence([s, i])``, split into one child stream per noise source, so a trial
is reproducible on its own (whatever the batch it is simulated in) and changing one source
(say the ADS noise level) leaves the others' normalised draws unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from qkf.core import units
from qkf.core.jit import kernel_array
from qkf.core.quat import compose_rotvecs, cumulative_rotation
from qkf.core.time_grid import epochs_in, outside_windows
from qkf.transfer_alignment.config import (
    CalibrationJump,
    Config,
    Maneuver,
    RandomEventParts,
    RandomEvents,
    RandomJump,
    RandomManeuvers,
    RandomRotations,
    Scenario,
    WalkSegment,
)
from qkf.transfer_alignment.model import calibration_matrix
from qkf.transfer_alignment.params import TruthParams, n_epochs

_AXES = {"x": 0, "y": 1, "z": 2}
# a new stream goes at the end: SeedSequence children are fixed by their index, so adding one
# leaves the draws of the others unchanged
_STREAMS = ("truth", "bias_walk", "calib_walk", "gyro", "ads_attitude", "ads_rate", "events")


@dataclass(frozen=True)
class ScenarioData:
    """Simulated truth and sensor data for ``B`` trials over ``N`` epochs (SI units).

    Attitudes are unit quaternions (scalar-last) of the body → inertial rotation.
    """

    t: np.ndarray  # (N,) s
    dt: float
    omega_true: np.ndarray  # (B, N, 3) rad/s (a broadcast view when all trials share it)
    q_true: np.ndarray  # (B, N, 4) (likewise)
    bias: np.ndarray  # (B, N, 3) rad/s
    calib: np.ndarray  # (B, N, 9)
    gyro: np.ndarray  # (B, N, 3) rad/s
    ads_q: np.ndarray  # (B, N, 4)
    ads_rate: np.ndarray  # (B, N, 3) rad/s
    has_meas: np.ndarray  # (N,) bool, or (B, N) when trials differ (recorded runs)
    trial_ids: np.ndarray  # (B,) the trial index each row was drawn for
    seed: int = 0  # the run's seed: with trial_ids, what methods seed their own draws from
    jump_t: np.ndarray | None = None  # (B,) s, each trial's first calibration jump (NaN: none)
    # (B, J) s, every calibration jump of each trial in time order, NaN-padded (J ≥ 1, so
    # jumps_t[:, 0] is jump_t)
    jumps_t: np.ndarray | None = None
    family: np.ndarray | None = None  # (B,) int, mixture component per trial (family_names)
    # (B,) rad, each trial's true ADS attitude σ_a, when the family draws it (else None: the
    # scenario's ads.attitude_sigma_arcsec in every trial)
    ads_sigma_rad: np.ndarray | None = None

    @property
    def n_trials(self) -> int:
        return int(self.gyro.shape[0])

    @property
    def n_epochs(self) -> int:
        return int(self.t.shape[0])


def orbit_rate(altitude_km: float) -> float:
    """Mean motion ``n = sqrt(μ / a³)`` of a circular orbit, rad/s."""
    a = units.R_EARTH + altitude_km * 1e3
    return float(np.sqrt(units.MU_EARTH / a**3))


def true_rates(sc: Scenario) -> np.ndarray:
    """Deterministic body rate ``ω(t_k)`` (N, 3) in rad/s: orbit rate plus manoeuvres.

    A manoeuvre covers the epochs whose step ``[t_k, t_k + Δt)`` starts inside it.
    """
    t = np.arange(n_epochs(sc)) * sc.dt_s
    w = np.zeros((t.size, 3))
    w[:, 1] = -orbit_rate(sc.altitude_km)
    for m in sc.maneuvers:
        # t is sorted: the covered epochs t_k ∈ [start − 1e-9, end − 1e-9) are one slice, found
        # by bisection (a mask over all epochs per manoeuvre costs N·M: 10 s for 10⁶ epochs)
        on = epochs_in(t, m.start_s - 1e-9, m.start_s + m.duration_s - 1e-9)
        w[on, _AXES[m.axis]] += m.rate_deg_s * units.DEG_PER_S
    return w


def measurement_mask(sc: Scenario) -> np.ndarray:
    """``True`` at epochs with an ADS measurement (outside every gap window)."""
    t = np.arange(n_epochs(sc)) * sc.dt_s
    return outside_windows(t, [(g.start_s, g.end_s) for g in sc.ads.gaps])


def calibration_walk_sigma(sc: Scenario) -> np.ndarray:
    """Random-walk intensity of the true calibration per step ``[t_k, t_k+1)``, 1/√s (N,)."""
    t = np.arange(n_epochs(sc)) * sc.dt_s
    sig = np.full(t.size, sc.calibration_walk.sigma_per_sqrt_s)
    for seg in sc.calibration_walk.segments:
        sig[epochs_in(t, seg.start_s, seg.end_s)] = seg.sigma_per_sqrt_s
    return sig


def calibration_jumps(sc: Scenario) -> np.ndarray:
    """Sum of the calibration jumps in effect at each epoch (N, 9), dimensionless."""
    t = np.arange(n_epochs(sc)) * sc.dt_s
    jumps = np.zeros((t.size, 9))
    for j in sc.calibration_jumps:
        after = t >= j.t_s - 1e-9
        jumps[after, 0:3] += np.asarray(j.scale_factor_ppm) * units.PPM
        jumps[after, 3:9] += np.asarray(j.misalignment_urad) * units.URAD
    return jumps


def first_jump_s(sc: Scenario) -> float:
    """Time of the scenario's first calibration jump, s (NaN without one)."""
    return min((j.t_s for j in sc.calibration_jumps), default=float("nan"))


def jump_times(sc: Scenario) -> list[float]:
    """Times of the scenario's calibration jumps in increasing order, s."""
    return sorted(j.t_s for j in sc.calibration_jumps)


def family_names(cfg: Config) -> tuple[str, ...]:
    """Names of the mixture's components, in the order of ``ScenarioData.family``'s indices
    (empty without a mixture)."""
    ev = cfg.scenario.random_events
    return () if ev is None or ev.mixture is None else tuple(c.name for c in ev.mixture)


def component_scenario(sc: Scenario, index: int) -> Scenario:
    """The scenario of component ``index`` of ``sc``'s mixture: ``sc`` with that component's
    events as its ``random_events`` (what a trial that drew the component draws from)."""
    ev = sc.random_events
    if ev is None or ev.mixture is None:
        raise ValueError("the scenario has no mixture of families")
    events = RandomEvents.model_validate(ev.mixture[index].events.model_dump())
    return sc.model_copy(update={"random_events": events})


def _draws_ads_sigma(sc: Scenario) -> bool:
    """Whether some trial of the scenario draws its own ADS attitude σ."""
    ev = sc.random_events
    if ev is None:
        return False
    parts: list[RandomEventParts] = [ev] if ev.mixture is None else [c.events for c in ev.mixture]
    return any(p.ads_attitude_sigma_arcsec is not None for p in parts)


def _sequence(start: float, spec: RandomManeuvers, rng: np.random.Generator) -> list[Maneuver]:
    axes: list[Literal["x", "y", "z"]] = ["x", "y", "z"]
    if spec.shuffle_axes:
        axes = [axes[i] for i in rng.permutation(3)]
    out = []
    for axis in axes:
        rate = rng.uniform(spec.rate_deg_s.low, spec.rate_deg_s.high)
        length = rng.uniform(spec.duration_s.low, spec.duration_s.high)
        out.append(Maneuver(start_s=start, duration_s=length, axis=axis, rate_deg_s=rate))
        start += length
    return out


def _jump_times(j: RandomJump | RandomRotations, rng: np.random.Generator) -> np.ndarray:
    """``count`` sorted jump times, s, at least ``min_separation_s`` apart: uniform on the
    allowed region (the construction is in :class:`~..config.RandomJump`). With one jump it is
    one ``U[low, high]`` draw, as it has always been."""
    shift = np.arange(j.count) * j.min_separation_s
    u = rng.uniform(j.t_s.low, j.t_s.high - shift[-1], j.count)
    return np.sort(u) + shift


def _draw_parts(sc: Scenario, ev: RandomEventParts, rng: np.random.Generator) -> Scenario:
    """``sc`` with the parts of ``ev`` drawn from ``rng``, in the documented order (drift,
    manoeuvres, jumps, ADS σ; :class:`~..config.RandomEvents`): a new part draws after the
    existing ones, so a family's draws never move when a later part is added to it."""
    update: dict[str, object] = {"random_events": None}
    maneuvers = list(sc.maneuvers)
    if ev.drift is not None:
        d = ev.drift
        start = rng.uniform(d.start_s.low, d.start_s.high)
        length = rng.uniform(d.duration_s.low, d.duration_s.high)
        log_sigma = rng.uniform(np.log(d.sigma_per_sqrt_s.low), np.log(d.sigma_per_sqrt_s.high))
        segment = WalkSegment(
            start_s=start, end_s=start + length, sigma_per_sqrt_s=float(np.exp(log_sigma))
        )
        update["calibration_walk"] = sc.calibration_walk.model_copy(update={"segments": [segment]})
    if ev.maneuvers is not None:
        maneuvers = _sequence(0.0, ev.maneuvers, rng)
    if ev.jump is not None:
        j = ev.jump
        again = ev.maneuvers or RandomManeuvers(shuffle_axes=False)
        jumps = []
        for t_jump in _jump_times(j, rng).tolist():
            sign = rng.choice([-1.0, 1.0], size=9) if j.random_sign else np.ones(9)
            sf = rng.uniform(j.scale_factor_ppm.low, j.scale_factor_ppm.high, 3) * sign[:3]
            ma = rng.uniform(j.misalignment_urad.low, j.misalignment_urad.high, 6) * sign[3:]
            jumps.append(
                CalibrationJump(
                    t_s=t_jump,
                    scale_factor_ppm=tuple(float(v) for v in sf),  # type: ignore[arg-type]
                    misalignment_urad=tuple(float(v) for v in ma),  # type: ignore[arg-type]
                )
            )
            if j.rotations_after:
                delay = j.rotations_delay_s
                start = t_jump + (0.0 if delay is None else rng.uniform(delay.low, delay.high))
                maneuvers += _sequence(start, again, rng)
        update["calibration_jumps"] = jumps
    if ev.ads_attitude_sigma_arcsec is not None:
        a = ev.ads_attitude_sigma_arcsec
        sigma = float(rng.uniform(a.low, a.high))
        update["ads"] = sc.ads.model_copy(update={"attitude_sigma_arcsec": sigma})
    if ev.rotations is not None:
        again = ev.maneuvers or RandomManeuvers(shuffle_axes=False)
        for t_start in _jump_times(ev.rotations, rng).tolist():
            maneuvers += _sequence(t_start, again, rng)
    update["maneuvers"] = maneuvers
    return sc.model_copy(update=update)


def draw_trial(sc: Scenario, rng: np.random.Generator) -> tuple[Scenario, int | None]:
    """The scenario of one trial of a randomized family, and the index of the mixture
    component it drew (None without a mixture): with a mixture, one component uniformly, then
    its events (:func:`component_scenario`); else the events of ``sc.random_events``."""
    ev = sc.random_events
    if ev is None:
        return sc, None
    if ev.mixture is None:
        return _draw_parts(sc, ev, rng), None
    family = int(rng.integers(len(ev.mixture)))
    return _draw_parts(sc, ev.mixture[family].events, rng), family


def draw_events(sc: Scenario, rng: np.random.Generator) -> Scenario:
    """The scenario of one trial of a randomized family: ``sc`` with the events of
    ``sc.random_events`` drawn from ``rng`` (:func:`draw_trial` without the component index).
    ``sc`` itself when nothing is drawn."""
    return draw_trial(sc, rng)[0]


def true_attitude(omega: np.ndarray, dt: float) -> np.ndarray:
    """Quaternions (N, 4) of ``C_{k+1} = C_k Exp(ω_k Δt)`` from ``C_0 = I``."""
    return cumulative_rotation(
        np.array([0.0, 0.0, 0.0, 1.0]), np.ascontiguousarray(omega[:-1] * dt)
    )


def trial_streams(seed: int, trial: int) -> dict[str, np.random.Generator]:
    """The independent generators of one trial, one per noise source."""
    children = np.random.SeedSequence([seed, trial]).spawn(len(_STREAMS))
    return {name: np.random.default_rng(ss) for name, ss in zip(_STREAMS, children, strict=True)}


def simulate(cfg: Config, seed: int, trials: np.ndarray | list[int] | int) -> ScenarioData:
    """Simulate the scenario of ``cfg`` for the given trial indices (or ``range(trials)``)."""
    sc = cfg.scenario
    tp = TruthParams.from_config(cfg)
    ids = np.arange(trials) if isinstance(trials, int) else np.asarray(trials, dtype=int)
    if ids.ndim != 1 or ids.size == 0:
        raise ValueError("trials must be a positive count or a non-empty list of indices")
    n, dt, b = tp.n_epochs, tp.dt, ids.size
    t = np.arange(n) * dt
    random = sc.random_events is not None
    # the nominal schedule: every trial's, unless each trial draws its own below
    walk_sigma = calibration_walk_sigma(sc)
    jump_t = np.full(b, first_jump_s(sc))
    trial_jumps = [jump_times(sc)] * b
    sigma_a = np.full(b, tp.sigma_a)  # the true ADS attitude σ per trial, rad
    mixture = random and sc.random_events is not None and sc.random_events.mixture is not None
    family = np.full(b, -1, dtype=int) if mixture else None
    if random:  # per-trial schedules
        omega_b, q_b = np.empty((b, n, 3)), np.empty((b, n, 4))
        walk_b, jumps_b = np.empty((b, n)), np.empty((b, n, 9))

    bias = np.empty((b, n, 3))
    calib = np.empty((b, n, 9))
    eta_v = np.empty((b, n, 3))
    nu_a = np.empty((b, n, 3))
    nu_r = np.empty((b, n, 3))
    for row, trial in enumerate(ids):
        g = trial_streams(seed, int(trial))
        if random:
            sc_trial, drawn_family = draw_trial(sc, g["events"])
            if family is not None and drawn_family is not None:
                family[row] = drawn_family
            trial_jumps[row] = jump_times(sc_trial)
            # same arithmetic as TruthParams: a family that draws no σ_a keeps it bit for bit
            sigma_a[row] = sc_trial.ads.attitude_sigma_arcsec * units.ARCSEC
            omega_b[row] = true_rates(sc_trial)
            q_b[row] = true_attitude(omega_b[row], dt)
            walk_b[row] = calibration_walk_sigma(sc_trial)
            jumps_b[row] = calibration_jumps(sc_trial)
            jump_t[row] = first_jump_s(sc_trial)
            walk_sigma = walk_b[row]
        if tp.randomize_truth:
            scale = sc.truth_prior_scale  # 1.0 multiplies exactly: the draws stay bit for bit
            b0 = g["truth"].normal(0.0, scale * tp.prior_sigma_b, 3)
            p0 = g["truth"].normal(0.0, scale * tp.prior_sigma_p, 9)
        else:
            b0, p0 = tp.b0, tp.p0
        db = g["bias_walk"].normal(0.0, tp.sigma_u * np.sqrt(dt), (n - 1, 3))
        bias[row, 0] = b0
        np.cumsum(db, axis=0, out=bias[row, 1:])
        bias[row, 1:] += b0
        dp = g["calib_walk"].normal(0.0, 1.0, (n - 1, 9)) * (walk_sigma[:-1, None] * np.sqrt(dt))
        calib[row, 0] = p0
        np.cumsum(dp, axis=0, out=calib[row, 1:])
        calib[row, 1:] += p0
        eta_v[row] = g["gyro"].normal(0.0, tp.sigma_v / np.sqrt(dt), (n, 3))
        nu_a[row] = g["ads_attitude"].normal(0.0, sigma_a[row], (n, 3))
        nu_r[row] = g["ads_rate"].normal(0.0, tp.sigma_r, (n, 3))
    if random:
        calib += jumps_b
        kw = np.einsum("bnij,bnj->bni", calibration_matrix(calib), omega_b)
        omega_all, q_all = omega_b, q_b
    else:  # one schedule for all trials (kept on this path: same arithmetic as ever)
        omega = true_rates(sc)
        q_true = true_attitude(omega, dt)
        calib += calibration_jumps(sc)[None]
        kw = np.einsum("bnij,nj->bni", calibration_matrix(calib), omega)
        omega_all = np.broadcast_to(omega, (b, n, 3))
        q_all = np.broadcast_to(q_true, (b, n, 4))
    gyro = omega_all + kw + bias + eta_v
    jumps_t = np.full((b, max(1, *map(len, trial_jumps))), np.nan)
    for row, times in enumerate(trial_jumps):
        jumps_t[row, : len(times)] = times
    ads_q = np.empty((b * n, 4))  # C_ADS = C Exp(ν_a)
    # writable C arrays: one trial's broadcast is a read-only view, another compiled copy
    q_rows = kernel_array(q_all, float, q_all.shape).reshape(-1, 4)
    compose_rotvecs(q_rows, kernel_array(nu_a, float, nu_a.shape).reshape(-1, 3), ads_q)
    return ScenarioData(
        t=t,
        dt=dt,
        omega_true=omega_all,
        q_true=q_all,
        bias=bias,
        calib=calib,
        gyro=gyro,
        ads_q=ads_q.reshape(b, n, 4),
        ads_rate=omega_all + nu_r,
        has_meas=measurement_mask(sc),
        trial_ids=ids,
        seed=seed,
        jump_t=jump_t,
        jumps_t=jumps_t,
        family=family,
        ads_sigma_rad=sigma_a if _draws_ads_sigma(sc) else None,
    )
