"""Configuration: YAML presets validated with pydantic, in display units (SPEC §1–§2).

Values in a config carry their unit in their name (``rate_deg_s``, ``attitude_sigma_arcsec``);
``qkf.transfer_alignment.scenario`` and ``qkf.transfer_alignment.filter`` convert to SI. Unknown keys are errors, so a typo never
silently falls back to a default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

PositiveFloat = Annotated[float, Field(gt=0.0)]
NonNegativeFloat = Annotated[float, Field(ge=0.0)]


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the file and the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Maneuver(_Strict):
    """A constant-rate rotation added to the orbit rate over ``[start_s, start_s + duration_s)``."""

    start_s: NonNegativeFloat
    duration_s: PositiveFloat
    axis: Literal["x", "y", "z"]
    rate_deg_s: float


class TimeWindow(_Strict):
    start_s: NonNegativeFloat
    end_s: NonNegativeFloat

    @model_validator(mode="after")
    def _ordered(self) -> TimeWindow:
        if self.end_s <= self.start_s:
            raise ValueError("end_s must be greater than start_s")
        return self


class WalkSegment(TimeWindow):
    """Calibration random-walk intensity over a window, in 1/√s."""

    sigma_per_sqrt_s: NonNegativeFloat


class CalibrationWalk(_Strict):
    """Random walk of the true calibration vector: ``p_{k+1} = p_k + N(0, σ(t)² Δt)``."""

    sigma_per_sqrt_s: NonNegativeFloat = 0.0
    segments: list[WalkSegment] = Field(default_factory=list)


class CalibrationJump(_Strict):
    """A step change of the true calibration at ``t_s``, added to every term of the group."""

    t_s: NonNegativeFloat
    misalignment_urad: float = 0.0
    scale_factor_ppm: float = 0.0


class GyroNoise(_Strict):
    arw_deg_sqrt_h: PositiveFloat = 4.0e-4
    rrw_deg_h_1_5: PositiveFloat = 1.0e-3


class Truth(_Strict):
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


class Ads(_Strict):
    """The master's attitude determination system, as it really is (truth side)."""

    attitude_sigma_arcsec: PositiveFloat = 3.0
    rate_sigma_degph: PositiveFloat = 0.02
    gaps: list[TimeWindow] = Field(default_factory=list)


def _default_maneuvers() -> list[Maneuver]:
    return [
        Maneuver(start_s=0.0, duration_s=100.0, axis="x", rate_deg_s=1.0),
        Maneuver(start_s=100.0, duration_s=100.0, axis="y", rate_deg_s=1.0),
        Maneuver(start_s=200.0, duration_s=100.0, axis="z", rate_deg_s=1.0),
    ]


class Scenario(_Strict):
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

    @model_validator(mode="after")
    def _fits(self) -> Scenario:
        if self.duration_s < self.dt_s:
            raise ValueError("duration_s must be at least one step (dt_s)")
        return self


class InitialSigma(_Strict):
    attitude_arcsec: PositiveFloat = 60.0
    bias_degph: PositiveFloat = 2.0
    calibration_ppm: PositiveFloat = 1500.0


class FilterConfig(_Strict):
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


class RunConfig(_Strict):
    trials: Annotated[int, Field(ge=1)] = 20
    seed: Annotated[int, Field(ge=0)] = 0
    kappa: PositiveFloat = 1.0
    chunk_trials: Annotated[int, Field(ge=1)] = 64
    workers: Annotated[int, Field(ge=1)] = 1  # local backend: processes (1 = this process)
    ray_address: str | None = None  # ray backend: cluster address (else RAY_ADDRESS, else local)


class ActionSet(_Strict):
    """The process-noise factors κ_i = 10^(log10_min + i · log10_step), i = 0 … count − 1."""

    log10_min: float = -2.0
    log10_step: PositiveFloat = 0.4
    count: Annotated[int, Field(ge=2, le=101)] = 11

    def values(self) -> list[float]:
        return [10.0 ** (self.log10_min + i * self.log10_step) for i in range(self.count)]


class SageHusaConfig(_Strict):
    forgetting: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.97
    adapt_r: bool = False  # also estimate the attitude measurement noise
    r_floor: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1  # σ̂_a ≥ r_floor · assumed σ_a
    r_warmup_s: Annotated[float, Field(ge=0.0)] = 100.0  # adapt R only once P has settled


class QkfConfig(_Strict):
    """Online Q-learning Kalman filter (SPEC §3)."""

    period_s: PositiveFloat = 10.0
    epsilon_start: Annotated[float, Field(ge=0.0, le=1.0)] = 0.2
    epsilon_end: Annotated[float, Field(ge=0.0, le=1.0)] = 0.02
    epsilon_decay_s: PositiveFloat = 900.0
    alpha: Annotated[float, Field(gt=0.0, le=1.0)] = 0.1
    gamma: Annotated[float, Field(ge=0.0, lt=1.0)] = 0.9


class MmaeConfig(_Strict):
    weight_floor: Annotated[float, Field(ge=0.0, lt=0.1)] = 1e-6


class TunedConfig(_Strict):
    """The oracle constant-κ KF: κ chosen with the truth on separate tuning seeds."""

    trials: Annotated[int, Field(ge=1)] = 8
    seed: Annotated[int, Field(ge=0)] = 1_000_003


class AdaptiveConfig(_Strict):
    actions: ActionSet = ActionSet()
    sage_husa: SageHusaConfig = SageHusaConfig()
    qkf: QkfConfig = QkfConfig()
    mmae: MmaeConfig = MmaeConfig()
    tuned: TunedConfig = TunedConfig()


class Sweep(_Strict):
    """A study over one config value: the benchmark runs once per value."""

    key: str
    values: list[Any] = Field(min_length=1)


class Config(_Strict):
    name: str = "custom"
    description: str = ""
    scenario: Scenario = Scenario()
    filter: FilterConfig = FilterConfig()
    run: RunConfig = RunConfig()
    adaptive: AdaptiveConfig = AdaptiveConfig()
    sweep: Sweep | None = None


def _parse_override(item: str) -> tuple[list[str], Any]:
    if "=" not in item:
        raise ConfigError(f"--set {item!r}: expected dotted.key=value")
    key, raw = item.split("=", 1)
    parts = [p for p in key.strip().split(".") if p]
    if not parts:
        raise ConfigError(f"--set {item!r}: empty key")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {item!r}: cannot parse value: {exc}") from exc
    return parts, value


def apply_override(data: dict[str, Any], item: str) -> None:
    """Apply one ``dotted.key=value`` override (value parsed as YAML) to a raw config dict."""
    parts, value = _parse_override(item)
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            node = node[_list_index(part, node, item)]
            continue
        if part not in node or node[part] is None:
            # Create intermediate mappings; validation then rejects keys that do not exist.
            node[part] = {}
        elif not isinstance(node[part], dict | list):
            raise ConfigError(f"--set {item!r}: {'.'.join(parts[: i + 1])} is not a mapping")
        node = node[part]
    last = parts[-1]
    if isinstance(node, list):
        node[_list_index(last, node, item)] = value
    else:
        node[last] = value


def _list_index(part: str, node: list[Any], item: str) -> int:
    if not part.lstrip("-").isdigit() or not -len(node) <= int(part) < len(node):
        raise ConfigError(f"--set {item!r}: {part!r} is not an index of a list of {len(node)}")
    return int(part)


def _format_validation(source: str, exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        loc = ".".join(str(x) for x in err["loc"]) or "(top level)"
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{source}: {loc}: {msg}")
    return "invalid configuration\n  " + "\n  ".join(lines)


def _as_defaults(cfg: Config) -> dict[str, Any]:
    return cfg.model_dump(mode="json")


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Read and validate a YAML config, then apply ``--set`` style overrides.

    Raises ``ConfigError`` with the file and field named when anything is wrong.
    """
    source = str(path) if path is not None else "<defaults>"
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"{source}: no such config file")
        try:
            loaded = yaml.safe_load(p.read_text())
        except yaml.YAMLError as exc:
            raise ConfigError(f"{source}: not valid YAML: {exc}") from exc
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"{source}: top level must be a mapping")
        data = loaded
    try:
        Config.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_validation(source, exc)) from None
    if overrides:
        # Overrides act on the fully populated config so that list items (maneuvers.1...)
        # and nested defaults can be addressed even when the file left them out.
        merged = _as_defaults(Config.model_validate(data))
        for item in overrides:
            apply_override(merged, item)
        data = merged
        source = f"{source} (with --set)"
    try:
        return Config.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_validation(source, exc)) from None
