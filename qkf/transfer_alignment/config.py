"""Configuration of the transfer-alignment problem: the YAML schema, in display units.

Values carry their unit in their name (``rate_deg_s``, ``attitude_sigma_arcsec``);
:mod:`qkf.transfer_alignment.params` converts them to SI. The schema is strict (unknown keys are
errors); the machinery (YAML, ``--set`` overrides, messages naming file and field) is
:mod:`qkf.core.config`. The meaning of every section is in docs/models.md and docs/methods.md.

Methods are configured under ``adaptive``: the built-in methods' sections are fields of
:class:`AdaptiveConfig`; a user's method declares a section of its own (docs/architecture.md,
"Recipe: add a method"), which the config holds as written until the methods of a run are
known and :func:`resolve_sections` validates it with the method's model.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

from pydantic import Field, ValidationError, model_validator

from qkf.core import presets
from qkf.core.config import (
    ConfigError,
    NonNegativeFloat,
    PositiveFloat,
    ProblemConfig,
    StrictModel,
    TimeWindow,
    apply_override,
    workload_error,
)
from qkf.transfer_alignment.adaptive import MAX_TRIALS, AdaptiveConfig


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


class LogUniform(Uniform):
    """A log-uniform distribution on ``[low, high]``, both positive (ordered as
    :class:`Uniform`)."""

    low: PositiveFloat
    high: PositiveFloat


MAX_RANDOM_JUMPS = 4
"""Upper bound on ``random_events.jump.count``."""


def _check_separation(count: int, separation: float, t_s: Uniform, what: str) -> None:
    """Refuse ``count`` times at least ``separation`` apart that do not fit strictly inside
    ``t_s`` (the allowed region must have a positive volume, else the times are not uniform on
    anything): ``(count − 1)`` separations, as long as there are two."""
    span = t_s.high - t_s.low
    need = (count - 1) * separation
    if count > 1 and need >= span:
        raise ValueError(
            f"min_separation_s: {count} {what} (count) at least {separation:g} s apart need a "
            f"t_s range longer than {need:g} s; t_s spans {span:g} s"
        )


class RandomManeuvers(StrictModel):
    """The calibration rotation sequence, drawn per trial: one rotation about each body axis,
    back to back from its start, in random order (``shuffle_axes``), each with its own rate and
    duration."""

    shuffle_axes: bool = True
    rate_deg_s: Uniform = Uniform(low=1.0, high=1.0)
    duration_s: Uniform = Uniform(low=100.0, high=100.0)


class RandomJump(StrictModel):
    """Calibration jumps drawn per trial (they replace ``calibration_jumps``): ``count`` jump
    times in ``t_s``, at least ``min_separation_s`` apart, and per jump and term a magnitude
    (and a random sign, if ``random_sign``). With ``rotations_after``, a rotation sequence
    starts at each jump, drawn as ``random_events.maneuvers`` (without those, an x, y, z
    sequence at 1 deg/s, 100 s each, after the fixed ``maneuvers``: list only the first
    sequence there).

    The times: with ``J = count``, ``d = min_separation_s`` and ``t_s = U[a, b]``, draw
    ``u_1 … u_J`` i.i.d. ``U[a, b − (J − 1) d]``, sort them and set ``t_i = u_(i) + (i − 1) d``.
    The shift is a one-to-one, volume-preserving map from ordered tuples onto the allowed
    region ``{a ≤ t_1, t_i + d ≤ t_(i+1), t_J ≤ b}``, so the times are uniform on it (what
    i.i.d. uniform times rejected until their gaps reach ``d`` would give, at a fixed cost of
    ``J`` draws). For ``J = 2``, with ``L = b − a − d``: ``(t_1 − a)/L ~ Beta(1, 2)``,
    ``(t_2 − a − d)/L ~ Beta(2, 1)`` and ``(t_2 − t_1 − d)/L ~ Beta(1, 2)``.
    """

    t_s: Uniform
    misalignment_urad: Uniform = Uniform(low=0.0, high=0.0)
    scale_factor_ppm: Uniform = Uniform(low=0.0, high=0.0)
    random_sign: bool = True
    rotations_after: bool = True
    count: Annotated[int, Field(ge=1, le=MAX_RANDOM_JUMPS)] = 1
    min_separation_s: NonNegativeFloat = 0.0
    # with rotations_after: the sequence starts this long after its jump (drawn per jump, just
    # before the sequence); None: at the jump. A change with a quiet stretch after it.
    rotations_delay_s: Uniform | None = None

    @model_validator(mode="after")
    def _fits(self) -> RandomJump:
        if self.rotations_delay_s is not None and (
            not self.rotations_after or self.rotations_delay_s.low < 0.0
        ):
            raise ValueError(
                "rotations_delay_s: needs rotations_after: true and a non-negative range"
            )
        _check_separation(self.count, self.min_separation_s, self.t_s, "jumps")
        return self


class RandomRotations(StrictModel):
    """Rotation sequences without a calibration change, drawn per trial: ``count`` start times
    in ``t_s``, at least ``min_separation_s`` apart (drawn as :class:`RandomJump`'s times),
    each a sequence drawn as ``random_events.maneuvers`` (without those, x, y, z at 1 deg/s,
    100 s each). What keeps "a rotation starts" from always meaning "the calibration changed"
    (docs/models.md, "Scenario families")."""

    t_s: Uniform
    count: Annotated[int, Field(ge=1, le=MAX_RANDOM_JUMPS)] = 1
    min_separation_s: NonNegativeFloat = 0.0

    @model_validator(mode="after")
    def _fits(self) -> RandomRotations:
        _check_separation(self.count, self.min_separation_s, self.t_s, "sequences")
        return self


class RandomDrift(StrictModel):
    """A thermal transient drawn per trial (it replaces the segments of ``calibration_walk``):
    the random walk has intensity ``sigma_per_sqrt_s`` (1/√s) over
    ``[start_s, start_s + duration_s)``, the walk's base intensity elsewhere."""

    start_s: Uniform
    duration_s: Uniform
    sigma_per_sqrt_s: LogUniform


class RandomEventParts(StrictModel):
    """The parts a trial's events are drawn from; each part, if given, replaces its fixed
    counterpart in the trial (``maneuvers``; ``calibration_jumps``; the segments of
    ``calibration_walk``; ``ads.attitude_sigma_arcsec``). Draw order: :class:`RandomEvents`."""

    maneuvers: RandomManeuvers | None = None
    jump: RandomJump | None = None
    drift: RandomDrift | None = None
    ads_attitude_sigma_arcsec: Uniform | None = None  # the true ADS attitude noise, arcsec
    rotations: RandomRotations | None = None  # rotation sequences without a change

    @model_validator(mode="after")
    def _positive_sigma(self) -> RandomEventParts:
        ads = self.ads_attitude_sigma_arcsec
        if ads is not None and ads.low <= 0.0:
            raise ValueError("ads_attitude_sigma_arcsec: low must be positive (a noise σ)")
        return self

    def parts(self) -> list[str]:
        """Names of the parts given."""
        return [name for name in RandomEventParts.model_fields if getattr(self, name) is not None]


class MixtureComponent(StrictModel):
    """One family of a mixture: its name (reports, :func:`~..scenario.family_names`) and its
    events (no mixture inside)."""

    name: Annotated[str, Field(min_length=1)]
    events: RandomEventParts


class RandomEvents(RandomEventParts):
    """Events drawn per trial (randomized scenario families, docs/models.md, "Scenario
    families"), from the trial's own ``events`` stream.

    Draw order, fixed so that adding a part never moves the draws of the parts before it:
    the mixture component (``mixture`` only: uniform over its entries), then the drift (start,
    length, log-intensity), the rotation sequence (axis order, then rate and duration per
    axis), the jumps (every time first; then per jump in time order: 9 signs, 3 scale factors,
    6 misalignments and its rotation sequence), the ADS attitude σ, the rotations without a
    change (every time first, then each sequence in time order). (The drift leads because
    ``thermal_drift_random`` gained its rotation draws after its transient: every (seed, trial)
    keeps the transient it had.)

    ``mixture``: each trial first draws one component uniformly, then that component's events;
    it stands alone (the parts go inside the components).
    """

    mixture: Annotated[list[MixtureComponent], Field(min_length=1)] | None = None

    @model_validator(mode="after")
    def _mixture_alone(self) -> RandomEvents:
        if self.mixture is None:
            return self
        if self.parts():
            raise ValueError(
                f"mixture: cannot stand next to {', '.join(self.parts())} (move them into the "
                "mixture's components)"
            )
        names = [c.name for c in self.mixture]
        if len(set(names)) != len(names):
            raise ValueError("mixture: component names must be unique")
        return self


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
    # with randomize_truth: the σ of the truth's draw relative to the filter's prior σ (1: the
    # filter's prior is the truth's law; a shift family draws wider)
    truth_prior_scale: PositiveFloat = 1.0
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
    # earliest start of the settled window of the summary metrics, s; each trial's own window
    # opens once its calibration CRLB is within settle_factor of its end-of-run value after its
    # opening rotations (qkf/transfer_alignment/settled.py)
    settled_s: NonNegativeFloat = 400.0
    settle_factor: Annotated[float, Field(gt=1.0)] = 2.0
    nees_every_s: PositiveFloat = 10.0  # methods report their covariance this often (NEES)
    baseline: str = "kf"  # the method others are compared with (paired.csv), if it is run
    bootstrap: Bootstrap = Bootstrap()


class RecordedConfig(StrictModel):
    """Reading recorded runs (``qkf bench CONFIG --data FILE``; docs/recorded_data.md).

    The data set the time grid: its step is the median row step, and every row step must be a
    whole number of it (within ``step_tolerance``); the filter propagates through the missing
    epochs of a longer step with the gyro reading held, without updates.
    """

    max_epochs: Annotated[int, Field(ge=2, le=MAX_EPOCHS)] = 5_000_000  # per file, grid epochs
    max_gap_s: PositiveFloat = 60.0  # longest time without an ADS measurement (attitude or rate)
    # of the step; 1e-3 of 0.1 s at 1 deg/s is 0.36″ of attitude, well under the ADS noise
    step_tolerance: Annotated[float, Field(gt=0.0, lt=0.5)] = 1e-3
    quaternion_tolerance: Annotated[float, Field(gt=0.0, lt=0.1)] = 1e-6  # |‖q‖ − 1|
    max_rate_rad_s: PositiveFloat = 10.0  # a larger |ω| is refused ("deg/s given?")
    chunk_rows: Annotated[int, Field(ge=1024, le=10_000_000)] = 262_144  # rows read at a time
    # the gyro and ADS rates against the rotation of the ADS attitudes: deg/s, ms, scalar-first
    # or inertial → body quaternions refused by name (recorded/conventions.py)
    check_conventions: bool = True
    ignore_columns: tuple[str, ...] = ()  # extra columns of the files, read past (never used)


class Sweep(StrictModel):
    """A study over one config value: the benchmark runs once per value."""

    key: str
    values: list[Any] = Field(min_length=1)


class Config(ProblemConfig):
    scenario: Scenario = Scenario()
    filter: FilterConfig = FilterConfig()
    run: RunConfig = RunConfig()
    adaptive: AdaptiveConfig = AdaptiveConfig()
    recorded: RecordedConfig = RecordedConfig()
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


SettingsT = TypeVar("SettingsT", bound=StrictModel)


def builtin_section(section: str) -> type[StrictModel] | None:
    """The model of a built-in section of ``adaptive`` (a field of :class:`AdaptiveConfig`:
    ``imm`` → :class:`ImmConfig`), or None for any other name (a user's section)."""
    field = AdaptiveConfig.model_fields.get(section)
    model = None if field is None else field.annotation
    return model if isinstance(model, type) and issubclass(model, StrictModel) else None


def read_section(
    cfg: Config, section: str, model: type[SettingsT], source: str = "config"
) -> SettingsT:
    """``cfg.adaptive.<section>`` as ``model`` (what ``method_settings`` returns).

    A built-in section is the config's own field (it must be of type ``model``). A user's
    section is validated from the mapping the config holds, or from an empty one when the
    config has none (the model's defaults; a required field is then reported missing). A
    benchmark has resolved it already (:func:`resolve_sections`: checked, defaults written in),
    so validating it again where the method runs gives the same settings, in any process.
    Raises :class:`ConfigError` naming ``adaptive.<section>.<field>``.
    """
    builtin = builtin_section(section)
    if builtin is not None:
        value = getattr(cfg.adaptive, section)
        if not isinstance(value, model):
            raise ConfigError(
                f"{source}: adaptive.{section}: the built-in section of type {builtin.__name__} "
                f"cannot be read as {model.__name__}"
            )
        return value
    raw = (cfg.adaptive.model_extra or {}).get(section, {})
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        lines = [f"{source}: {e}" for e in _section_errors(section, exc)]
        raise ConfigError(_invalid(lines)) from None
    except RecursionError:
        raise ConfigError(f"{source}: adaptive.{section}: nested too deeply") from None


def resolve_sections(
    cfg: Config, claims: Mapping[str, tuple[type[StrictModel], str]], source: str = "config"
) -> Config:
    """``cfg`` with every user section of ``adaptive`` validated by the model that reads it.

    ``claims``: section → (model, who reads it, e.g. ``method 'mine'``), for the methods of a
    run. A claimed user section is validated (or its defaults taken, if the config has none)
    and held in its resolved form, every field written out (``model_dump(mode="json")``), so
    that a manifest records the settings the run used. A user section that nothing claims is
    refused as an unknown key, and a claim on a built-in section must use its model. Every
    problem is reported at once, one line each (``source: adaptive.mine.gain: message``), in a
    :class:`ConfigError`. ``cfg`` itself is returned when no method reads a user section.
    """
    extra = cfg.adaptive.model_extra or {}
    problems: list[str] = []
    readers = sorted(s for s in claims if builtin_section(s) is None)
    known = f"; user sections read by this run: {', '.join(readers)}" if readers else ""
    for section in extra:
        if section not in claims:
            problems.append(
                f"adaptive.{section}: unknown key (no method of this run reads it{known})"
            )
    resolved: dict[str, dict[str, Any]] = {}
    for section, (model, who) in claims.items():
        builtin = builtin_section(section)
        if builtin is not None:
            if model is not builtin:
                problems.append(
                    f"adaptive.{section}: {who} reads it as {model.__name__}, but it is the "
                    f"built-in section of type {builtin.__name__}"
                )
            continue
        try:
            settings = model.model_validate(extra.get(section, {}))
        except ValidationError as exc:
            problems += _section_errors(section, exc)
            continue
        except RecursionError:
            problems.append(f"adaptive.{section}: nested too deeply")
            continue
        resolved[section] = settings.model_dump(mode="json")
    if problems:
        raise ConfigError(_invalid([f"{source}: {p}" for p in problems]))
    if not resolved:  # no user section (unclaimed ones were refused above): nothing to change
        return cfg
    # validated already, section by section: a copy with the resolved sections in place
    adaptive = cfg.adaptive.model_copy(update=resolved)
    return cfg.model_copy(update={"adaptive": adaptive})


def _section_errors(section: str, exc: ValidationError) -> list[str]:
    """``adaptive.<section>.<field>: message`` per problem, worded as
    :func:`qkf.core.config.format_validation` words those of a whole config."""
    lines = []
    for err in exc.errors():
        loc = ".".join(["adaptive", section, *(str(x) for x in err["loc"])])
        msg = (
            "unknown key" if err["type"] == "extra_forbidden" else " ".join(str(err["msg"]).split())
        )
        lines.append(f"{loc}: {msg}")
    return lines


def _invalid(lines: list[str]) -> str:
    return "invalid configuration\n  " + "\n  ".join(lines)


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


PRESETS = "transfer_alignment"
"""The problem's preset folder (``configs/transfer_alignment/``); its studies are in
``studies/`` below it."""
STUDIES = f"{PRESETS}/studies"


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Read and validate a config — a path or a preset name (``thermal_snap``) — then apply
    ``--set`` style overrides. Raises :class:`ConfigError` naming the file and the field."""
    return presets.load_preset(Config, path, PRESETS, overrides)


def load_scenario(path: str | Path, overrides: list[str] | None = None) -> Config:
    """:func:`load_config` for a use that runs no method (an environment, the CRLB): a user
    section under ``adaptive`` is then read by nothing, so it is refused as an unknown key, as
    any typo is (``ConfigError`` naming the file)."""
    cfg = load_config(path, overrides)
    source = str(presets.resolve(path, PRESETS)) + (" (with --set)" if overrides else "")
    return resolve_sections(cfg, {}, source)


__all__ = [
    "Config",
    "ConfigError",
    "apply_override",
    "check_workload",
    "load_config",
    "load_scenario",
]
