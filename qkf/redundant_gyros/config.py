"""Configuration of the redundant-gyro problem: the YAML schema, in display units.

Rates and biases are in deg/s everywhere in this problem (docs/redundant_gyros.md, "Units");
misalignments are in degrees here and converted to rad by :mod:`qkf.redundant_gyros.geometry`;
scale-factor errors λ are dimensionless. The schema is strict (unknown keys are errors); the
machinery (YAML, ``--set`` overrides, messages naming file and field) is :mod:`qkf.core.config`.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, model_validator

from qkf.core.actions import ActionSet
from qkf.core.config import (
    ConfigError,
    NonNegativeFloat,
    PositiveFloat,
    ProblemConfig,
    StrictModel,
    workload_error,
)

GyroId = Annotated[str, Field(pattern=r"^[A-Za-z][A-Za-z0-9_]*$", max_length=32)]
Vector3 = tuple[float, float, float]

MAX_EPOCHS = 10_000_000
"""Upper bound on ``duration_s / dt_s`` (a typo such as 1e30 would exhaust memory)."""
MAX_TRIALS = 10_000_000
MAX_TRIAL_EPOCHS = 10_000_000_000
"""Upper bound on the trial-epochs of ``qkf gyros bench`` (:func:`check_workload`): trials ×
bench epochs × fault groups (kinds × sizes). A trial-epoch costs about 0.5 to 0.9 µs, the
simulation included (docs/redundant_gyros.md, "Speed"), so 10¹⁰ is a few hours; 10⁷ trials of
10⁵ epochs would take years. Only counts per trial are kept, so this bounds time, not memory.
"""
MAX_CHUNK_TRIAL_EPOCHS = 20_000_000
"""Upper bound on the trials simulated at once × their epochs: the memory of one chunk of the
bench (``bench.chunk_trials``) and of the bench's UKF accuracy run (``bench.ukf_trials``, all at
once, with a 4 × 4 covariance per trial-epoch). A bench chunk takes about 250 bytes per
trial-epoch with five gyros (measured; more with more gyros), so about 5 GB at the limit; the
UKF, at about 300 µs per step, would run for about two hours. Twice :data:`MAX_EPOCHS`, so
every accepted scenario runs with small enough chunks."""
PRESETS = "redundant_gyros"
"""The problem's preset folder (``configs/redundant_gyros/``)."""


class GyroSpec(StrictModel):
    """One single-axis gyro: its sensing axis ``w`` and reference axis ``u`` (body frame), given
    as vectors or by the two mounting angles (``w = [sin α sin β, cos α, sin α cos β]``,
    ``u = [−cos α sin β, sin α, −cos α cos β]``). ``v = w × u``. Error coefficients left out
    take the unit's nominal values."""

    id: GyroId
    w: Vector3 | None = None
    u: Vector3 | None = None
    alpha_deg: float | None = None
    beta_deg: float | None = None
    bias_deg_s: float | None = None
    scale: float | None = None
    delta_u_deg: float | None = None
    delta_v_deg: float | None = None
    noise_deg_s: PositiveFloat | None = None

    @model_validator(mode="after")
    def _one_axis_form(self) -> GyroSpec:
        vectors = self.w is not None or self.u is not None
        angles = self.alpha_deg is not None or self.beta_deg is not None
        if vectors == angles:
            raise ValueError("give either w and u, or alpha_deg and beta_deg")
        if vectors and (self.w is None or self.u is None):
            raise ValueError("w and u must both be given")
        if angles and (self.alpha_deg is None or self.beta_deg is None):
            raise ValueError("alpha_deg and beta_deg must both be given")
        if self.scale is not None and self.scale >= 1.0:
            raise ValueError("scale (λ) must be below 1")
        return self


def _five_gyros() -> list[GyroSpec]:
    return [
        GyroSpec(id="X", w=(1.0, 0.0, 0.0), u=(0.0, 1.0, 0.0)),
        GyroSpec(id="Y", w=(0.0, 1.0, 0.0), u=(0.0, 0.0, 1.0)),
        GyroSpec(id="Z", w=(0.0, 0.0, 1.0), u=(1.0, 0.0, 0.0)),
        GyroSpec(id="S", alpha_deg=55.0, beta_deg=45.0),
        GyroSpec(id="T", alpha_deg=55.0, beta_deg=75.0),
    ]


class Nominal(StrictModel):
    """Ground-calibrated (known) error coefficients, the default of every gyro."""

    bias_deg_s: float = 0.01
    scale: Annotated[float, Field(lt=1.0)] = 0.002
    delta_u_deg: float = 0.0
    delta_v_deg: float = 0.0


class UnitConfig(StrictModel):
    """The redundant unit: any n ≥ 4 single-axis gyros."""

    gyros: list[GyroSpec] = Field(default_factory=_five_gyros, min_length=4, max_length=64)
    nominal: Nominal = Nominal()
    noise_deg_s: PositiveFloat = 0.001  # white-noise sd per sample, every gyro by default

    @model_validator(mode="after")
    def _unique_ids(self) -> UnitConfig:
        ids = [g.id for g in self.gyros]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"gyro ids must be unique: {', '.join(dup)} repeated")
        return self

    def ids(self) -> list[str]:
        return [g.id for g in self.gyros]


class BodyRate(StrictModel):
    """Body rate ``ω(t) = c + A sin(2π t / T + φ)`` per axis, deg/s."""

    constant_deg_s: Vector3 = (0.5, -0.3, 0.2)
    amplitude_deg_s: Vector3 = (3.0, 3.0, 3.0)
    period_s: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = (20.0, 14.0, 9.0)
    phase_deg: Vector3 = (0.0, 60.0, 120.0)


FaultKind = Literal[
    "bias_step", "bias_ramp", "scale_step", "misalignment_step", "stuck", "noise_increase"
]
FAULT_UNITS: dict[str, str] = {
    "bias_step": "deg/s added to the bias b",
    "bias_ramp": "deg/s per s: the bias grows at this rate",
    "scale_step": "added to λ (dimensionless)",
    "misalignment_step": "[Δδ_u, Δδ_v] in deg",
    "stuck": "deg/s added to the frozen last healthy reading",
    "noise_increase": "factor on the white-noise sd (> 0)",
}
"""What ``size`` means for each fault kind."""


class Fault(StrictModel):
    """A fault of one gyro from ``t_s`` on; ``size`` as :data:`FAULT_UNITS` says."""

    gyro: GyroId
    t_s: NonNegativeFloat
    kind: FaultKind
    size: float | tuple[float, float]

    @model_validator(mode="after")
    def _size_fits_kind(self) -> Fault:
        pair = isinstance(self.size, tuple)
        if self.kind == "misalignment_step" and not pair:
            raise ValueError("size: misalignment_step takes [delta_u_deg, delta_v_deg]")
        if self.kind != "misalignment_step" and pair:
            raise ValueError(f"size: {self.kind} takes one number ({FAULT_UNITS[self.kind]})")
        if self.kind == "noise_increase" and not (isinstance(self.size, float) and self.size > 0):
            raise ValueError("size: noise_increase takes a positive factor")
        return self


class OnsetStep(StrictModel):
    """Sd of the step each coefficient of the onset's gyro takes at the onset: one normal draw
    per episode and coefficient (0: no step)."""

    bias_deg_s: NonNegativeFloat = 0.0
    scale: NonNegativeFloat = 0.0
    delta_u_deg: NonNegativeFloat = 0.0
    delta_v_deg: NonNegativeFloat = 0.0


class OnsetDriftRates(StrictModel):
    """Random-walk intensities of the onset gyro's true coefficients, per √s: the walk's
    variance grows as ``σ² (t − t₀)`` from its start ``t₀`` (0: no walk)."""

    bias_deg_s_per_sqrt_s: NonNegativeFloat = 0.0
    scale_per_sqrt_s: NonNegativeFloat = 0.0
    delta_u_deg_per_sqrt_s: NonNegativeFloat = 0.0
    delta_v_deg_per_sqrt_s: NonNegativeFloat = 0.0


class OnsetDrift(StrictModel):
    """An unknown fault onset and drifting coefficients of one gyro, drawn per episode
    (docs/redundant_gyros.md, "Onset and drift"): the onset time uniform in ``onset_s``
    (s; a draw at or after the end of the run never happens), a step of the coefficients at
    the onset (``step``, normal sds) and a random walk of them (``drift``, per √s) from the
    onset on (``drift_from: onset``) or from the start of the run (``start``)."""

    gyro: GyroId
    onset_s: tuple[NonNegativeFloat, NonNegativeFloat]
    step: OnsetStep = OnsetStep()
    drift: OnsetDriftRates = OnsetDriftRates()
    drift_from: Literal["onset", "start"] = "onset"
    # noise levels drawn per episode, unknown to the filter (docs/redundant_gyros.md, "Noise
    # levels"): a log-uniform factor on every drift rate (the coefficients' instability) and one
    # on the gyro's white-noise sd (its angle random walk); null: no draw, factor 1
    drift_scale: tuple[PositiveFloat, PositiveFloat] | None = None
    noise_factor: tuple[PositiveFloat, PositiveFloat] | None = None

    @model_validator(mode="after")
    def _range(self) -> OnsetDrift:
        if self.onset_s[0] > self.onset_s[1]:
            raise ValueError("onset_s: [earliest, latest] with earliest ≤ latest")
        for name in ("drift_scale", "noise_factor"):
            r = getattr(self, name)
            if r is not None and r[0] > r[1]:
                raise ValueError(f"{name}: [low, high] with low ≤ high")
        return self


class OnsetComponent(StrictModel):
    """One family of an onset mixture: its name (a preset's, for reports) and its ``onset``
    (None: constant coefficients, the no-change control)."""

    name: str
    onset: OnsetDrift | None = None


class Scenario(StrictModel):
    dt_s: PositiveFloat = 0.1
    duration_s: PositiveFloat = 600.0
    body_rate: BodyRate = BodyRate()
    faults: list[Fault] = Field(default_factory=list)
    onset: OnsetDrift | None = None  # None: no drawn onset, constant coefficients
    # a mixture of families (docs/redundant_gyros.md, "Gyro families"): each episode first draws
    # one component uniformly, from its own stream, then that component's onset; instead of onset
    onset_mixture: Annotated[list[OnsetComponent], Field(min_length=1)] | None = None

    def onset_specs(self) -> list[OnsetDrift]:
        """Every onset an episode may draw: ``onset``, or the mixture components' ones."""
        if self.onset_mixture is None:
            return [] if self.onset is None else [self.onset]
        return [c.onset for c in self.onset_mixture if c.onset is not None]

    @model_validator(mode="after")
    def _one_onset(self) -> Scenario:
        if self.onset_mixture is None:
            return self
        if self.onset is not None:
            raise ValueError("onset_mixture: cannot stand next to onset (move it into a component)")
        names = [c.name for c in self.onset_mixture]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"onset_mixture: {', '.join(twice)} named twice")
        gyros = {o.gyro for o in self.onset_specs()}
        if len(gyros) > 1:
            raise ValueError(
                f"onset_mixture: the components' onsets are on gyros {', '.join(sorted(gyros))}; "
                "one gyro for all (the calibrated one)"
            )
        return self

    @model_validator(mode="after")
    def _fits(self) -> Scenario:
        if self.duration_s < 2 * self.dt_s:
            raise ValueError("duration_s must be at least two steps (dt_s)")
        if self.duration_s / self.dt_s > MAX_EPOCHS:
            raise ValueError(
                f"duration_s / dt_s = {self.duration_s / self.dt_s:.3g} epochs; at most "
                f"{MAX_EPOCHS:,}"
            )
        return self


def _paper_models() -> list[list[str]]:
    return [["X", "Y", "Z"], ["X", "S", "T"], ["Y", "Z", "S", "T"]]


class ThreeCrossConfig(StrictModel):
    """Three-cross reconstruction: three models (gyro ids, ≥ 3 each), the signature band and the
    sliding window over which in-band epochs are counted."""

    models: list[list[GyroId]] = Field(default_factory=_paper_models, min_length=3, max_length=3)
    band: PositiveFloat = 0.2
    window_epochs: Annotated[int, Field(ge=1, le=100_000)] = 50
    null_samples: Annotated[int, Field(ge=1000, le=10_000_000)] = 200_000

    @model_validator(mode="after")
    def _sizes(self) -> ThreeCrossConfig:
        for i, m in enumerate(self.models):
            if len(m) < 3:
                raise ValueError(f"models.{i}: a model needs at least 3 gyros")
            if len(set(m)) != len(m):
                raise ValueError(f"models.{i}: a gyro is listed twice")
        return self


class FdiConfig(StrictModel):
    false_alarm_probability: Annotated[float, Field(gt=0.0, lt=0.5)] = 1e-3  # per epoch
    glt_window_epochs: Annotated[int, Field(ge=1, le=100_000)] = 25
    threecross: ThreeCrossConfig = ThreeCrossConfig()
    reconfigure_by: Literal["threecross", "glt"] = "threecross"


class FeatureTable(StrictModel):
    """How ``feature_with_errors`` is formed: noise-free readings with the nominal errors left in
    and a bias step of ``fault_deg_s`` on the gyro, at body rate ``body_rate_deg_s``."""

    fault_deg_s: float = 0.1
    body_rate_deg_s: Vector3 = (1.0, 1.0, 1.0)

    @model_validator(mode="after")
    def _nonzero(self) -> FeatureTable:
        if self.fault_deg_s == 0.0:
            raise ValueError("fault_deg_s must not be 0")
        return self


class InitialSigma(StrictModel):
    """Prior sd of the calibrated coefficients around their nominal values."""

    bias_deg_s: PositiveFloat = 0.2
    scale: PositiveFloat = 0.005
    delta_deg: PositiveFloat = 20.0


class Tolerance(StrictModel):
    """When a calibration counts as converged (every error within these, to the end)."""

    bias_deg_s: PositiveFloat = 0.002
    scale: PositiveFloat = 0.001
    delta_deg: PositiveFloat = 0.5


class ProcessNoise(StrictModel):
    """Random-walk intensities of the calibrated coefficients (κ = 1)."""

    bias_deg_s_per_sqrt_s: NonNegativeFloat = 1e-6
    scale_per_sqrt_s: NonNegativeFloat = 1e-7
    delta_deg_per_sqrt_s: NonNegativeFloat = 1e-5


class SigmaPoints(StrictModel):
    """Merwe's scaled sigma points; ``kappa`` None means 3 − n."""

    alpha: Annotated[float, Field(gt=0.0, le=1.0)] = 1.0
    beta: NonNegativeFloat = 2.0
    kappa: float | None = None


class CalibrationConfig(StrictModel):
    """UKF calibration of the isolated gyro (docs/redundant_gyros.md, "UKF")."""

    gyro: GyroId | None = None  # None: the gyro the FDI isolates most often
    source: Literal["threecross", "glt"] = "threecross"
    start_s: NonNegativeFloat | None = None  # None: the first epoch it is isolated
    triad: list[GyroId] | None = None  # None: the best-conditioned healthy triad
    initial_sigma: InitialSigma = InitialSigma()
    process_noise: ProcessNoise = ProcessNoise()
    kappa: PositiveFloat = 1.0
    sigma_points: SigmaPoints = SigmaPoints()
    converged_within: Tolerance = Tolerance()

    @model_validator(mode="after")
    def _triad(self) -> CalibrationConfig:
        if self.triad is not None and (len(self.triad) != 3 or len(set(self.triad)) != 3):
            raise ValueError("triad: three different gyro ids")
        return self


class Bootstrap(StrictModel):
    resamples: Annotated[int, Field(ge=100, le=1_000_000)] = 2000
    level: Annotated[float, Field(gt=0.5, lt=1.0)] = 0.95


BENCH_KINDS: tuple[FaultKind, ...] = (
    "bias_step",
    "bias_ramp",
    "scale_step",
    "misalignment_step",
    "stuck",
    "noise_increase",
)


class BenchConfig(StrictModel):
    """``qkf gyros bench``: fault kinds × sizes in σ units (docs/redundant_gyros.md, "Bench")."""

    trials: Annotated[int, Field(ge=1, le=MAX_TRIALS)] = 100
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    duration_s: PositiveFloat = 60.0
    fault_time_s: NonNegativeFloat = 30.0
    kinds: list[FaultKind] = Field(default_factory=lambda: list(BENCH_KINDS), min_length=1)
    sizes_sigma: list[PositiveFloat] = Field(default_factory=lambda: [2.0, 4.0, 8.0, 16.0])
    ramp_s: PositiveFloat = 10.0  # a ramp reaches its size after this long
    chunk_trials: Annotated[int, Field(ge=1, le=MAX_TRIALS)] = 64
    ukf_trials: Annotated[int, Field(ge=0, le=100_000)] = 10
    bootstrap: Bootstrap = Bootstrap()
    # how the trials run (qkf.core.montecarlo); the numbers do not depend on either
    workers: Annotated[int, Field(ge=1, le=1024)] = 1  # local backend: processes (1 = here)
    ray_address: str | None = None  # ray backend: cluster address (else RAY_ADDRESS, else local)

    @model_validator(mode="after")
    def _fault_inside(self) -> BenchConfig:
        if not self.fault_time_s < self.duration_s:
            raise ValueError("fault_time_s must be inside the run (below duration_s)")
        if not self.sizes_sigma:
            raise ValueError("sizes_sigma: at least one size")
        return self


class EnvironmentConfig(StrictModel):
    period_s: PositiveFloat = 10.0
    actions: ActionSet = ActionSet()


class RunConfig(StrictModel):
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0


class GyrosConfig(ProblemConfig):
    unit: UnitConfig = UnitConfig()
    scenario: Scenario = Scenario()
    fdi: FdiConfig = FdiConfig()
    features: FeatureTable = FeatureTable()
    calibration: CalibrationConfig = CalibrationConfig()
    bench: BenchConfig = BenchConfig()
    environment: EnvironmentConfig = EnvironmentConfig()
    run: RunConfig = RunConfig()

    @model_validator(mode="after")
    def _ids_known(self) -> GyrosConfig:
        known = set(self.unit.ids())

        def check(where: str, gid: str) -> None:
            if gid not in known:
                raise ValueError(f"{where}: unknown gyro {gid!r} (unit: {', '.join(known)})")

        for i, m in enumerate(self.fdi.threecross.models):
            for gid in m:
                check(f"fdi.threecross.models.{i}", gid)
        for i, f in enumerate(self.scenario.faults):
            check(f"scenario.faults.{i}.gyro", f.gyro)
            if f.t_s >= self.scenario.duration_s:
                raise ValueError(f"scenario.faults.{i}.t_s: after the end of the run")
        if self.scenario.onset is not None:
            check("scenario.onset.gyro", self.scenario.onset.gyro)
        for i, c in enumerate(self.scenario.onset_mixture or []):
            if c.onset is not None:
                check(f"scenario.onset_mixture.{i}.onset.gyro", c.onset.gyro)
        if self.calibration.gyro is not None:
            check("calibration.gyro", self.calibration.gyro)
        for gid in self.calibration.triad or []:
            check("calibration.triad", gid)
        if self.calibration.gyro is not None and self.calibration.gyro in (
            self.calibration.triad or []
        ):
            raise ValueError("calibration.triad: must not contain the calibrated gyro")
        return self

    @model_validator(mode="after")
    def _workload(self) -> GyrosConfig:
        # too big a bench is refused on load, before any work; the command line checks its
        # --trials, and the UKF run, with check_workload(cfg, trials)
        try:
            _check_bench(self, None)
        except ConfigError as exc:
            raise workload_error(exc) from None
        return self


def epochs_of(duration_s: float, dt_s: float) -> int:
    """Epochs of a run, as :func:`qkf.redundant_gyros.scenario.epochs` makes them (that module
    imports this one)."""
    return max(2, math.floor(duration_s / dt_s + 1e-9))


def check_workload(cfg: GyrosConfig, trials: int | None = None) -> None:
    """Refuse a ``qkf gyros bench`` too big to finish: bench epochs above :data:`MAX_EPOCHS`,
    its trial-epochs above :data:`MAX_TRIAL_EPOCHS`, or more than
    :data:`MAX_CHUNK_TRIAL_EPOCHS` trial-epochs at once (a bench chunk, or the UKF accuracy run
    over the config's scenario). Raises :class:`ConfigError` naming the fields, the product and
    the limit.

    ``trials``: the bench's trials (the command line's ``--trials``); ``None`` means
    ``bench.trials``. Loading a config checks all but the UKF run (which only the bench does,
    so a long scenario stays usable by the other commands).
    """
    _check_bench(cfg, trials)
    b = cfg.bench
    epochs = epochs_of(cfg.scenario.duration_s, cfg.scenario.dt_s)
    if b.ukf_trials * epochs > MAX_CHUNK_TRIAL_EPOCHS:
        raise ConfigError(
            f"bench.ukf_trials × epochs (scenario.duration_s / scenario.dt_s) = "
            f"{b.ukf_trials:,} × {epochs:,} = {b.ukf_trials * epochs:.3g} trial-epochs, all at "
            f"once; at most {MAX_CHUNK_TRIAL_EPOCHS:.0e} (the UKF run's memory and time): set "
            f"bench.ukf_trials to {MAX_CHUNK_TRIAL_EPOCHS // epochs:,} or less"
        )


def _check_bench(cfg: GyrosConfig, trials: int | None) -> None:
    """The checks of :func:`check_workload` on the ``bench`` section's own runs."""
    b = cfg.bench
    n_trials = b.trials if trials is None else trials
    who = "bench.trials" if trials is None or trials == b.trials else "--trials"
    epochs = epochs_of(b.duration_s, cfg.scenario.dt_s)
    what = "epochs (bench.duration_s / scenario.dt_s)"
    if epochs > MAX_EPOCHS:
        raise ConfigError(f"{what} = {epochs:.3g}; at most {MAX_EPOCHS:,}")
    groups = len(b.kinds) * len(b.sizes_sigma)
    total = n_trials * epochs * groups
    if total > MAX_TRIAL_EPOCHS:
        raise ConfigError(
            f"{who} × {what} × fault groups (bench.kinds × bench.sizes_sigma) = "
            f"{n_trials:,} × {epochs:,} × {groups} = {total:.3g} trial-epochs; at most "
            f"{MAX_TRIAL_EPOCHS:.0e} (run time grows with it): lower {who} or bench.duration_s"
        )
    chunk = min(b.chunk_trials, n_trials)
    if chunk * epochs > MAX_CHUNK_TRIAL_EPOCHS:
        size = (
            "bench.chunk_trials" if chunk == b.chunk_trials else f"min(bench.chunk_trials, {who})"
        )
        raise ConfigError(
            f"{size} × {what} = {chunk:,} × {epochs:,} = {chunk * epochs:.3g} trial-epochs in "
            f"one chunk; at most {MAX_CHUNK_TRIAL_EPOCHS:.0e} (the memory of a chunk's arrays): "
            f"set bench.chunk_trials to {MAX_CHUNK_TRIAL_EPOCHS // epochs:,} or less"
        )


__all__ = [
    "ConfigError",
    "Fault",
    "GyrosConfig",
    "OnsetDrift",
    "check_workload",
]
