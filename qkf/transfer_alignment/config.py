"""Configuration of the transfer-alignment problem: the YAML schema, in display units.

Values carry their unit in their name (``rate_deg_s``, ``attitude_sigma_arcsec``);
:mod:`qkf.transfer_alignment.params` converts them to SI. The schema is strict (unknown keys are
errors); the machinery (YAML, ``--set`` overrides, messages naming file and field) is
:mod:`qkf.core.config`. The meaning of every section is in docs/models.md and docs/methods.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from qkf.core import presets
from qkf.core.actions import ActionSet
from qkf.core.config import (
    ConfigError,
    NonNegativeFloat,
    PositiveFloat,
    StrictModel,
    TimeWindow,
    apply_override,
    load_model,
    workload_error,
)
from qkf.transfer_alignment.alarms import NIS_ALARM, QUIET_S


class Maneuver(StrictModel):
    """A constant-rate rotation added to the orbit rate over ``[start_s, start_s + duration_s)``."""

    start_s: NonNegativeFloat
    duration_s: PositiveFloat
    axis: Literal["x", "y", "z"]
    rate_deg_s: float


class WalkSegment(TimeWindow):
    """Calibration random-walk intensity over a window, in 1/√s."""

    sigma_per_sqrt_s: NonNegativeFloat


class CalibrationWalk(StrictModel):
    """Random walk of the true calibration vector: ``p_{k+1} = p_k + N(0, σ(t)² Δt)``."""

    sigma_per_sqrt_s: NonNegativeFloat = 0.0
    segments: list[WalkSegment] = Field(default_factory=list)


class CalibrationJump(StrictModel):
    """A step change of the true calibration at ``t_s``: one value added to every term of the
    group, or one value per term (6 misalignments in ``p`` order, 3 scale factors)."""

    t_s: NonNegativeFloat
    misalignment_urad: float | tuple[float, float, float, float, float, float] = 0.0
    scale_factor_ppm: float | tuple[float, float, float] = 0.0


class Uniform(StrictModel):
    """A uniform distribution on ``[low, high]`` (``low == high``: a constant)."""

    low: float
    high: float

    @model_validator(mode="after")
    def _ordered(self) -> Uniform:
        if self.high < self.low:
            raise ValueError("high must be at least low")
        return self


class LogUniform(StrictModel):
    """A log-uniform distribution on ``[low, high]``, both positive."""

    low: PositiveFloat
    high: PositiveFloat

    @model_validator(mode="after")
    def _ordered(self) -> LogUniform:
        if self.high < self.low:
            raise ValueError("high must be at least low")
        return self


class RandomManeuvers(StrictModel):
    """The calibration rotation sequence, drawn per trial: one rotation about each body axis,
    back to back from its start, in random order (``shuffle_axes``), each with its own rate and
    duration."""

    shuffle_axes: bool = True
    rate_deg_s: Uniform = Uniform(low=1.0, high=1.0)
    duration_s: Uniform = Uniform(low=100.0, high=100.0)


class RandomJump(StrictModel):
    """A calibration jump drawn per trial (it replaces ``calibration_jumps``): its time, and per
    term a magnitude (and a random sign, if ``random_sign``). With ``rotations_after``, a second
    rotation sequence starts at the jump, drawn as ``random_events.maneuvers`` (without those,
    an x, y, z sequence at 1 deg/s, 100 s each, after the fixed ``maneuvers``: list only the
    first sequence there)."""

    t_s: Uniform
    misalignment_urad: Uniform = Uniform(low=0.0, high=0.0)
    scale_factor_ppm: Uniform = Uniform(low=0.0, high=0.0)
    random_sign: bool = True
    rotations_after: bool = True


class RandomDrift(StrictModel):
    """A thermal transient drawn per trial (it replaces the segments of ``calibration_walk``):
    the random walk has intensity ``sigma_per_sqrt_s`` (1/√s) over
    ``[start_s, start_s + duration_s)``, the walk's base intensity elsewhere."""

    start_s: Uniform
    duration_s: Uniform
    sigma_per_sqrt_s: LogUniform


class RandomEvents(StrictModel):
    """Events drawn per trial (randomized scenario families, docs/models.md): each part, if
    given, replaces its fixed counterpart (``maneuvers``; ``calibration_jumps``; a segment of
    ``calibration_walk``) in every trial, drawn from the trial's own stream."""

    maneuvers: RandomManeuvers | None = None
    jump: RandomJump | None = None
    drift: RandomDrift | None = None


class GyroNoise(StrictModel):
    arw_deg_sqrt_h: PositiveFloat = 4.0e-4
    rrw_deg_h_1_5: PositiveFloat = 1.0e-3


class Truth(StrictModel):
    bias_degph: tuple[float, float, float] = (1.0, -0.8, 0.6)
    scale_factor_ppm: tuple[float, float, float] = (300.0, -200.0, 250.0)
    misalignment_urad: tuple[float, float, float, float, float, float] = (
        500.0,
        -300.0,
        400.0,
        -450.0,
        350.0,
        -250.0,
    )


class Ads(StrictModel):
    """The master's attitude determination system, as it really is (truth side)."""

    attitude_sigma_arcsec: PositiveFloat = 3.0
    rate_sigma_degph: PositiveFloat = 0.02
    gaps: list[TimeWindow] = Field(default_factory=list)


MAX_EPOCHS = 10_000_000
"""Upper bound on ``duration_s / dt_s``: beyond it a typo (1e30) would exhaust memory."""
MAX_TRIALS = 10_000_000
"""Upper bound on Monte Carlo trial counts."""
MAX_TRIAL_EPOCHS = 1_000_000_000
"""Upper bound on trials × epochs, the total work of a benchmark (:func:`check_workload`).

Each trial-epoch costs tens of µs of filtering per method on one core (simulation included),
so 10⁹ is hours to days of CPU per method, and the benchmark keeps every trial's κ trace
until the end: trials × epochs / (κ sampling) floats per adaptive method, 0.8 GB at the limit
with the default sampling (every 10 epochs) and 8 GB when κ is sampled every epoch. 1,000
trials of a day at 1 s (86,400 epochs), or 100 trials of the longest scenario
(:data:`MAX_EPOCHS`), fit; 10⁷ trials of 10⁵ epochs (10¹², a typo) would run for years and
exhaust memory long before its end.
"""
MAX_CHUNK_TRIAL_EPOCHS = 20_000_000
"""Upper bound on the trials of one chunk × epochs: the memory of one chunk's arrays.

A chunk's trials are simulated and filtered together: the truth and the measurements, then
for each method its (chunk, epochs, 16) estimates and their errors, about 1.5 kB per
trial-epoch in all (measured), so about 30 GB at the limit. It is twice :data:`MAX_EPOCHS`, so
every accepted scenario runs with small enough chunks (``run.chunk_trials``); a chunk never
holds more than the run's trials.
"""


def _default_maneuvers() -> list[Maneuver]:
    return [
        Maneuver(start_s=0.0, duration_s=100.0, axis="x", rate_deg_s=1.0),
        Maneuver(start_s=100.0, duration_s=100.0, axis="y", rate_deg_s=1.0),
        Maneuver(start_s=200.0, duration_s=100.0, axis="z", rate_deg_s=1.0),
    ]


class Scenario(StrictModel):
    dt_s: PositiveFloat = 1.0
    duration_s: PositiveFloat = 3600.0
    altitude_km: PositiveFloat = 700.0
    maneuvers: list[Maneuver] = Field(default_factory=_default_maneuvers)
    gyro: GyroNoise = GyroNoise()
    truth: Truth = Truth()
    randomize_truth: bool = False
    calibration_walk: CalibrationWalk = CalibrationWalk()
    calibration_jumps: list[CalibrationJump] = Field(default_factory=list)
    ads: Ads = Ads()
    random_events: RandomEvents | None = None

    @model_validator(mode="after")
    def _fits(self) -> Scenario:
        if self.duration_s < self.dt_s:
            raise ValueError("duration_s must be at least one step (dt_s)")
        if self.duration_s / self.dt_s > MAX_EPOCHS:
            raise ValueError(
                f"duration_s / dt_s = {self.duration_s / self.dt_s:.3g} epochs; at most "
                f"{MAX_EPOCHS:,} (memory grows with trials × epochs)"
            )
        return self


class InitialSigma(StrictModel):
    attitude_arcsec: PositiveFloat = 60.0
    bias_degph: PositiveFloat = 2.0
    calibration_ppm: PositiveFloat = 1500.0


class FilterConfig(StrictModel):
    """What the filter assumes. Noise values left out default to the scenario's true ones."""

    matching: Literal["attitude", "attitude_rate"] = "attitude_rate"
    qp0: PositiveFloat = 1.0e-14
    attitude_sigma_arcsec: PositiveFloat | None = None
    rate_sigma_degph: PositiveFloat | None = None
    arw_deg_sqrt_h: PositiveFloat | None = None
    rrw_deg_h_1_5: PositiveFloat | None = None
    initial_sigma: InitialSigma = InitialSigma()
    quadrature_nodes: Annotated[int, Field(ge=2, le=16)] = 5
    rate_noise_correlation: bool = True


class Bootstrap(StrictModel):
    """Percentile bootstrap over trials for the intervals of summary.csv and paired.csv."""

    resamples: Annotated[int, Field(ge=100, le=1_000_000)] = 10_000
    level: Annotated[float, Field(gt=0.5, lt=1.0)] = 0.95


class RunConfig(StrictModel):
    trials: Annotated[int, Field(ge=1, le=MAX_TRIALS)] = 20
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    kappa: PositiveFloat = 1.0
    chunk_trials: Annotated[int, Field(ge=1, le=MAX_TRIALS)] = 64
    workers: Annotated[int, Field(ge=1, le=1024)] = 1  # local backend: processes (1 = here)
    ray_address: str | None = None  # ray backend: cluster address (else RAY_ADDRESS, else local)
    settled_s: NonNegativeFloat = 400.0  # start of the settled window of the summary metrics
    nees_every_s: PositiveFloat = 10.0  # methods report their covariance this often (NEES)
    baseline: str = "kf"  # the method others are compared with (paired.csv), if it is run
    bootstrap: Bootstrap = Bootstrap()


class SageHusaConfig(StrictModel):
    forgetting: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.97
    adapt_r: bool = False  # also estimate the attitude measurement noise
    r_floor: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1  # σ̂_a ≥ r_floor · assumed σ_a
    r_warmup_s: Annotated[float, Field(ge=0.0)] = 100.0  # adapt R only once P has settled


class QkfConfig(StrictModel):
    """Online Q-learning Kalman filter (docs/methods.md)."""

    period_s: PositiveFloat = 10.0
    epsilon_start: Annotated[float, Field(ge=0.0, le=1.0)] = 0.2
    epsilon_end: Annotated[float, Field(ge=0.0, le=1.0)] = 0.02
    epsilon_decay_s: PositiveFloat = 900.0
    alpha: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1
    gamma: Annotated[float, Field(ge=0.0, lt=1.0)] = 0.9
    # departures from the paper's rule, off by default (docs/methods.md, "QKF options"):
    switch_threshold: NonNegativeFloat = 0.0  # switch only if max Q(s, ·) exceeds it
    hysteresis: NonNegativeFloat = 0.0  # … and exceeds Q(s, s) by more than this
    reward_normalization: Literal["none", "running_rms"] = "none"


class MmaeConfig(StrictModel):
    weight_floor: Annotated[float, Field(ge=0.0, lt=0.1)] = 1e-6


class ImmConfig(StrictModel):
    """Interacting multiple models over the κ action set (docs/methods.md)."""

    p_stay: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.95  # per mixing interval
    switching: Literal["uniform", "neighbours"] = "uniform"
    mix_every: Annotated[int, Field(ge=1)] = 1  # epochs between mixings


class FadingConfig(StrictModel):
    """Strong-tracking (fading-memory) filter (docs/methods.md)."""

    forgetting: PositiveFloat = 0.95  # ρ of the innovation covariance estimate
    softening: Annotated[float, Field(ge=1.0)] = 4.0  # β
    lambda_max: Annotated[float, Field(ge=1.0)] = 10.0


class VbakfConfig(StrictModel):
    """Variational-Bayes AKF, Huang et al. 2018 (docs/methods.md)."""

    iterations: Annotated[int, Field(ge=1, le=1000)] = 10
    tau: Annotated[float, Field(ge=0.0)] = 3.0  # weight of the nominal prediction P̃⁻
    forgetting: Annotated[float, Field(gt=0.0, le=1.0)] = 0.9816843611112658  # ρ = 1 − e⁻⁴
    r_prior_dof: PositiveFloat = 3.0  # τ_R: û₀ = m + 1 + τ_R, Û₀ = τ_R R̃
    adapt_p: bool = True
    adapt_r: bool = True


class CovarianceMatchingConfig(StrictModel):
    """Innovation-based covariance matching, Mehra; Mohamed & Schwarz (docs/methods.md)."""

    window: Annotated[int, Field(ge=1, le=100_000)] = 30  # measurement epochs
    warmup_s: NonNegativeFloat = 100.0
    adapt_r: bool = True
    r_floor: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1  # σ̂_a ≥ r_floor · assumed σ_a


class TunedConfig(StrictModel):
    """The oracle constant-κ KF: κ chosen with the truth on separate tuning seeds."""

    trials: Annotated[int, Field(ge=1, le=MAX_TRIALS)] = 8
    seed: Annotated[int, Field(ge=0)] = 1_000_003


class OracleConfig(StrictModel):
    """The oracle schedule (an upper bound, not a flight method): κ_base, then κ_after for a
    window after each trial's true jump time; all chosen with the truth on tuning seeds."""

    windows_s: list[PositiveFloat] = Field(default=[50.0, 100.0, 200.0, 400.0, 800.0], min_length=1)
    metric: Literal["ma_urad_settled", "sf_ppm_settled", "calibration_settled"] = (
        "calibration_settled"
    )


class AlarmBurstConfig(StrictModel):
    """The alarm-burst method: the oracle's schedule started by an innovation alarm instead of
    the true jump time (docs/methods.md, "Alarm burst")."""

    period_s: PositiveFloat = 10.0  # decision period: NIS averaged and κ held over it
    nis_alarm: PositiveFloat = NIS_ALARM  # mean NIS per row above which a period alarms
    quiet_s: NonNegativeFloat = QUIET_S  # calm that separates two changes


class AdaptiveConfig(StrictModel):
    actions: ActionSet = ActionSet()
    sage_husa: SageHusaConfig = SageHusaConfig()
    qkf: QkfConfig = QkfConfig()
    mmae: MmaeConfig = MmaeConfig()
    tuned: TunedConfig = TunedConfig()
    imm: ImmConfig = ImmConfig()
    fading: FadingConfig = FadingConfig()
    vbakf: VbakfConfig = VbakfConfig()
    covariance_matching: CovarianceMatchingConfig = CovarianceMatchingConfig()
    oracle: OracleConfig = OracleConfig()
    alarm_burst: AlarmBurstConfig = AlarmBurstConfig()


class Sweep(StrictModel):
    """A study over one config value: the benchmark runs once per value."""

    key: str
    values: list[Any] = Field(min_length=1)


class Config(StrictModel):
    name: str = "custom"
    description: str = ""
    scenario: Scenario = Scenario()
    filter: FilterConfig = FilterConfig()
    run: RunConfig = RunConfig()
    adaptive: AdaptiveConfig = AdaptiveConfig()
    sweep: Sweep | None = None

    @model_validator(mode="after")
    def _workload(self) -> Config:
        # a config whose run.trials × epochs is too much is refused on load, before any work.
        # Not its chunk size: only a benchmark uses it (an environment or a test may load a long
        # scenario with the preset's chunk_trials), and the commands that run one check it,
        # and their --trials, with check_workload(cfg, trials)
        try:
            _check_total(self, None)
        except ConfigError as exc:
            raise workload_error(exc) from None
        return self


def epochs_of(scenario: Scenario) -> int:
    """Epochs of a scenario, ``round(duration_s / dt_s)`` (as
    :func:`qkf.transfer_alignment.params.n_epochs`, which imports this module)."""
    return round(scenario.duration_s / scenario.dt_s)


def check_workload(cfg: Config, trials: int | None = None) -> None:
    """Refuse a benchmark too big to finish: ``trials × epochs`` above
    :data:`MAX_TRIAL_EPOCHS` or one chunk's ``trials × epochs`` above
    :data:`MAX_CHUNK_TRIAL_EPOCHS`. Raises :class:`ConfigError` naming the fields, the product
    and the limit.

    ``trials``: the trials the run will do (the command line's ``--trials``); ``None`` means
    ``run.trials``. A chunk holds ``min(run.chunk_trials, trials)`` trials. Loading a config
    checks ``run.trials × epochs`` only (the chunk size matters to a benchmark alone).
    """
    n_trials, who, epochs, what = _check_total(cfg, trials)
    chunk = min(cfg.run.chunk_trials, n_trials)
    if chunk * epochs > MAX_CHUNK_TRIAL_EPOCHS:
        size = (
            "run.chunk_trials" if chunk == cfg.run.chunk_trials else f"min(run.chunk_trials, {who})"
        )
        raise ConfigError(
            f"{size} × {what} = {chunk:,} × {epochs:,} = {chunk * epochs:.3g} trial-epochs in "
            f"one chunk; at most {MAX_CHUNK_TRIAL_EPOCHS:.0e} (the memory of a chunk's arrays): "
            f"set run.chunk_trials to {MAX_CHUNK_TRIAL_EPOCHS // epochs:,} or less"
        )


def _check_total(cfg: Config, trials: int | None) -> tuple[int, str, int, str]:
    """The total-work check of :func:`check_workload`; returns the trials, how they are named,
    the epochs and how they are named."""
    n_trials = cfg.run.trials if trials is None else trials
    who = "run.trials" if trials is None or trials == cfg.run.trials else "--trials"
    epochs = epochs_of(cfg.scenario)
    what = "epochs (scenario.duration_s / scenario.dt_s)"
    total = n_trials * epochs
    if total > MAX_TRIAL_EPOCHS:
        raise ConfigError(
            f"{who} × {what} = {n_trials:,} × {epochs:,} = {total:.3g} trial-epochs; at most "
            f"{MAX_TRIAL_EPOCHS:.0e} (run time and per-trial κ traces grow with it): lower "
            f"{who} or scenario.duration_s"
        )
    return n_trials, who, epochs, what


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Read and validate a config — a path or a preset name (``thermal_snap``) — then apply
    ``--set`` style overrides. Raises :class:`ConfigError` naming the file and the field."""
    if path is None:
        return load_model(Config, None, overrides)
    resolved = presets.resolve(path)
    if not resolved.exists() and presets.is_preset_name(path):
        known = ", ".join(n for n in presets.preset_names() if not n.startswith("train_"))
        raise ConfigError(f"{path}: no such config file or preset (presets: {known})")
    return load_model(Config, resolved, overrides)


__all__ = ["Config", "ConfigError", "apply_override", "check_workload", "load_config"]
