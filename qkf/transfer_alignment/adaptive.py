"""``adaptive``: how κ is chosen. The action set, and the settings section of every built-in
method, one :class:`~qkf.core.config.StrictModel` each (its defaults and checks); a user's
method brings its own model (docs/architecture.md, "Recipe: add a method"). The sections are
checked and read through :mod:`.config` (``resolve_sections``, ``read_section``) and the
methods' declarations (:func:`qkf.transfer_alignment.methods.base.uses_settings`).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

from qkf.core.actions import ActionSet
from qkf.core.config import NonNegativeFloat, PositiveFloat, StrictModel

MAX_TRIALS = 10_000_000
"""Upper bound on Monte Carlo trial counts."""

JudgedMetric = Literal["state_settled", "ma_urad_settled", "sf_ppm_settled", "calibration_settled"]
"""Criteria the truth-tuned methods can be tuned for (settled window, RMS over tuning trials);
``state_settled`` is the whole-state metric (docs/methods.md, "Judging")."""


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

    p_stay: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.95  # Π_ii, per mixing interval
    switching: Literal["uniform", "neighbours"] = "uniform"  # where the mass 1 − p_stay goes
    mix_every: Annotated[int, Field(ge=1)] = 1  # epochs between mixings (the interval M)


class FadingConfig(StrictModel):
    """Strong-tracking (fading-memory) filter (docs/methods.md)."""

    forgetting: PositiveFloat = 0.95  # ρ of V_k = (ρ V_{k−1} + ν νᵀ)/(1 + ρ)
    softening: Annotated[float, Field(ge=1.0)] = 4.0  # β in N_k = V_k − β R − H Q Hᵀ
    lambda_max: Annotated[float, Field(ge=1.0)] = 10.0  # upper bound of one inflation λ


class VbakfConfig(StrictModel):
    """Variational-Bayes AKF, Huang et al. 2018 (docs/methods.md)."""

    iterations: Annotated[int, Field(ge=1, le=1000)] = 10  # N, fixed-point iterations
    tau: Annotated[float, Field(ge=0.0)] = 3.0  # weight of the nominal prediction P̃⁻
    forgetting: Annotated[float, Field(gt=0.0, le=1.0)] = 0.9816843611112658  # ρ = 1 − e⁻⁴
    r_prior_dof: PositiveFloat = 3.0  # τ_R: û₀ = m + 1 + τ_R, Û₀ = τ_R R̃
    adapt_p: bool = True  # infer P⁻ (false: P̂⁻ = P̃⁻, R only)
    adapt_r: bool = True  # infer R_a (false: R̂ = R̃)


class CovarianceMatchingConfig(StrictModel):
    """Innovation-based covariance matching, Mehra; Mohamed & Schwarz (docs/methods.md)."""

    window: Annotated[int, Field(ge=1, le=100_000)] = 30  # W, measurement epochs
    warmup_s: NonNegativeFloat = 100.0  # innovations enter the window from this time on
    adapt_r: bool = True
    r_floor: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1  # σ̂_a ≥ r_floor · assumed σ_a


TUNING_SEEDS = (1_000_000, 2_000_000)
"""Benchmark seeds ``[low, high)`` reserved for tuning with the truth (docs/environment.md,
"Seed ranges"): ``adaptive.tuned.seed`` lies here, and a run judged on such a seed has no
tuning seeds left (its tuned methods would be judged on the trials they were tuned on)."""


class TunedConfig(StrictModel):
    """Tuning with the truth on separate tuning seeds: the constant-κ KF (``kf-tuned``), the
    ``clock``, and the seeds and criterion every truth-tuned method shares."""

    # every tuned method's trials (the same budget for all: docs/methods.md, "Tuned baselines")
    trials: Annotated[int, Field(ge=1, le=MAX_TRIALS)] = 16
    seed: Annotated[int, Field(ge=TUNING_SEEDS[0], lt=TUNING_SEEDS[1])] = 1_000_003
    metric: JudgedMetric = "state_settled"


class OptunaConfig(StrictModel):
    """Hyperparameter tuning of the classical methods' ``-tuned`` variants with Optuna (TPE):
    ``evaluations`` settings, each run on ``adaptive.tuned.trials`` trials of the tuning seed,
    scored by ``adaptive.tuned.metric``; results are cached per scenario, seed and budget."""

    evaluations: Annotated[int, Field(ge=1, le=100_000)] = 50
    sampler_seed: Annotated[int, Field(ge=0)] = 0


class GlrConfig(StrictModel):
    """Change detection on the innovations with a CUSUM of the log-likelihood ratio, and a
    reset of the calibration block of P on alarm (docs/methods.md, "GLR reset").

    ``threshold`` h: with no change the statistic drifts down and the mean time between false
    alarms grows like e^h; over 64 ``paper`` trials of 3600 s the largest value a trial reached
    was 11.7 (median 6.3), while each of 64 ``thermal_snap_random`` jumps took it past h at the
    first measurement after the jump. ``quiet_s`` keeps a later alarm of the same change (the
    next rotation axis) from re-opening P again.
    """

    # the defaults are glr-tuned's settings on thermal_snap_random (50 evaluations × 16 tuning
    # trials, state_settled; docs/methods.md, "GLR reset"), to 4 digits
    inflation: Annotated[float, Field(gt=1.0, le=1e6)] = 11.74  # λ: S under a change is λ S
    threshold: PositiveFloat = 73.41  # h: alarm when the CUSUM statistic exceeds it
    reset_ppm: PositiveFloat = 129.4  # calibration σ added (in quadrature) on alarm, ppm/µrad
    quiet_s: NonNegativeFloat = 584.6  # no second reset this soon after one
    kappa: PositiveFloat = 1.0  # the filter's constant κ


class NisRuleConfig(StrictModel):
    """The three-number NIS rule (docs/methods.md, "NIS rule"): ``κ_burst`` for ``hold_s``
    after any decision period whose mean NIS per measurement row exceeds ``nis_threshold``,
    else ``κ_base``. The defaults are the rule that reproduced the shipped policy
    ``ppo_mixed_v3`` within 0.5 % on four families (issue 33): κ_base = 0.025 (the action
    10^-1.6), κ_burst = 100, 20 s after NIS > 4."""

    period_s: PositiveFloat = 10.0  # decision period: NIS averaged and κ held over it
    nis_threshold: PositiveFloat = 4.0
    kappa_base: PositiveFloat = 10.0**-1.6
    kappa_burst: PositiveFloat = 100.0
    hold_s: NonNegativeFloat = 20.0


class HindsightConfig(StrictModel):
    """The per-trial best κ schedule with the truth known (docs/methods.md, "Hindsight"):
    piecewise constant per decision period over the action set, found by coordinate descent
    over blocks of decreasing length (``blocks_s``, each a multiple of ``period_s``).

    ``focus_s``: a block length shorter than it is tried only within ``focus_s`` of a switch
    of the trial's schedule (where the κ changes), as the longer lengths left it; ``null``
    tries every block at every length (about four times the cost with the default blocks).

    ``screen_s``: run each candidate only this long past its block, and carry on to the end of
    the run only the ``screen_keep`` best of each trial by then; ``null`` runs every candidate
    to the end (exact coordinate descent, slower).

    ``restarts``: that many more searches per trial, each from a random schedule (one action
    per ``blocks_s[0]``, uniform, seeded by the run's seed, the trial and the restart) instead of
    the best constant; the best of all searches is the schedule, and the spread of their optima
    is the certificate printed beside it.
    """

    period_s: PositiveFloat = 10.0  # the agents' decision period
    blocks_s: list[PositiveFloat] = Field(default=[400.0, 200.0, 100.0, 50.0, 20.0], min_length=1)
    passes: Annotated[int, Field(ge=1, le=100)] = 1  # sweeps per block length
    focus_s: PositiveFloat | None = 100.0
    screen_s: PositiveFloat | None = None
    screen_keep: Annotated[int, Field(ge=1, le=1000)] = 3
    # searches from a random start (per trial, seeded); the best of all is kept, and how far
    # apart their optima are is the certificate (docs/methods.md, "Hindsight")
    restarts: Annotated[int, Field(ge=0, le=20)] = 1

    @model_validator(mode="after")
    def _whole_periods(self) -> HindsightConfig:
        for block in self.blocks_s:
            if abs(block / self.period_s - round(block / self.period_s)) > 1e-6 or (
                block < self.period_s
            ):
                raise ValueError(f"blocks_s: {block:g} s is not a multiple of period_s")
        return self


class ClockConfig(StrictModel):
    """The best open-loop κ(t) (docs/methods.md, "Clock"): piecewise constant on blocks of
    ``block_s``, tuned with the truth on the tuning seeds by coordinate descent."""

    block_s: PositiveFloat = 300.0
    passes: Annotated[int, Field(ge=1, le=100)] = 3


class OracleConfig(StrictModel):
    """The oracle schedule (an upper bound, not a flight method): κ_base, then κ_after for a
    window after each trial's true jump time; all chosen with the truth on tuning seeds."""

    windows_s: list[PositiveFloat] = Field(default=[50.0, 100.0, 200.0, 400.0, 800.0], min_length=1)
    metric: JudgedMetric = "state_settled"


class AlarmBurstConfig(StrictModel):
    """The alarm-burst method: the oracle's schedule started by an innovation alarm instead of
    the true jump time (docs/methods.md, "Alarm burst"). ``nis_alarm`` and ``quiet_s`` are also
    what the environment's observation v2 sees (:func:`qkf.transfer_alignment.alarms.change_clock`
    builds the clock of both from them).

    ``nis_alarm``: a period whose mean NIS per measurement row exceeds it is an alarm. Under a
    consistent filter the 10-epoch mean of χ²/m has mean 1 and standard deviation ≈ 0.2–0.3, so
    a chance alarm at 4 is a > 10σ event; a calibration jump seen during a rotation gives
    10 … 100.

    ``quiet_s``: an alarm after at least this long without one starts a new change. A
    calibration change raises an alarm at each rotation axis that makes part of it observable
    (60–150 s apart in the thermal scenarios): 600 s is longer than a three-axis rotation
    sequence, and shorter than the time between calibration events of the thermal scenarios.
    """

    period_s: PositiveFloat = 10.0  # decision period: NIS averaged and κ held over it
    nis_alarm: PositiveFloat = 4.0  # mean NIS per row above which a period alarms
    quiet_s: NonNegativeFloat = 600.0  # calm that separates two changes


def _finite_setting(value: Any) -> Any:
    """``value`` unchanged, unless a number anywhere inside it is NaN or infinite: a user's
    section is held as written until its method's model validates it, and a config never holds
    a non-finite number, validated or not (as :class:`StrictModel` refuses them)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise PydanticCustomError("finite_number", "Input should be a finite number")
    if isinstance(value, dict):
        for item in value.values():
            _finite_setting(item)
    elif isinstance(value, list | tuple):
        for item in value:
            _finite_setting(item)
    return value


RawSetting = Annotated[Any, AfterValidator(_finite_setting)]
"""One value of a user's method section as written in YAML or ``--set`` (finite numbers only)."""


class AdaptiveConfig(StrictModel):
    """How κ is chosen: the action set, and one section per method that has settings.

    The built-in methods' sections are the fields below. Any other key is the section of a
    user's method (``adaptive.mine``): a method declares it with
    :func:`~qkf.transfer_alignment.methods.base.uses_settings`, and reads it with
    :func:`~qkf.transfer_alignment.methods.base.method_settings`. Because a config is loaded
    before the methods of a run are known (``qkf bench`` resolves ``--methods`` after loading),
    such a section is held as written, a mapping of finite values; once the methods are known,
    :func:`resolve_sections` validates it with the method's own model, and refuses a section
    that no method of the run reads (a typo must not pass silently).
    """

    # extra keys are user sections (held raw until resolve_sections); every value a mapping,
    # so a scalar or a list in their place is refused on load, with the key named
    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, dict[str, RawSetting]] = Field(init=False)

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
    optuna: OptunaConfig = OptunaConfig()
    glr: GlrConfig = GlrConfig()
    nis_rule: NisRuleConfig = NisRuleConfig()
    hindsight: HindsightConfig = HindsightConfig()
    clock: ClockConfig = ClockConfig()
