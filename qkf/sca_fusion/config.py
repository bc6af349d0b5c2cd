"""Configuration of the star-camera + angular-accelerometer fusion (docs/sca_fusion.md).

Estimator values follow GROOPS's InstrumentStarCameraAngularAccelerometerFusion defaults and are
SI (their unit is in their name); the simulation states its display units in the names
(``noise_arcsec``). The schema is strict; the machinery is :mod:`qkf.core.config`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field, model_validator

from qkf.core import presets
from qkf.core.config import (
    ConfigError,
    NonNegativeFloat,
    PositiveFloat,
    ProblemConfig,
    StrictModel,
    TimeWindow,
)

Vector3 = tuple[float, float, float]
PositiveVector3 = tuple[PositiveFloat, PositiveFloat, PositiveFloat]


class AccCalibration(StrictModel):
    """Accelerometer bias or scale, per axis: constant per arc (``interval_s: null``) or
    piecewise constant over intervals of ``interval_s`` from the arc's start."""

    estimate: bool = True
    interval_s: PositiveFloat | None = None


class EulerCorrection(StrictModel):
    """Gyroscopic term of a non-cubic proof mass: the instrument reports
    ``ω̇ + I⁻¹ (ω × I ω)``; the correction removes it (docs/sca_fusion.md). Only the ratios of
    the principal moments matter (GROOPS: GRACE proof mass)."""

    enabled: bool = True
    proof_mass_inertia: PositiveVector3 = (1.037e-5, 1.959e-5, 1.037e-5)


class Estimator(StrictModel):
    """The least-squares fusion (GROOPS names in docs/sca_fusion.md)."""

    sigma_star_camera_rad: PositiveFloat = 1.0  # sigmaStarcamera: a-priori factor
    sigma_accelerometer_rad_s2: PositiveVector3 = (1.0e-6, 2.0e-7, 2.0e-7)
    estimate_sigma_sca_per_axis: bool = False
    estimate_sigma_acc_per_axis: bool = True
    variance_component_estimation: bool = True
    huber: PositiveFloat | None = 2.5  # null: no robust reweighting
    huber_power: NonNegativeFloat = 1.5
    interpolation_degree: Annotated[int, Field(ge=2, le=8)] = 2
    iteration_count: Annotated[int, Field(ge=1, le=1000)] = 15
    convergence_sigma0: PositiveFloat = 1.0e-5
    weak_prior_deg: PositiveFloat = 0.25  # epochs without a star-camera observation
    acc_bias: AccCalibration = AccCalibration(estimate=True)
    acc_scale: AccCalibration = AccCalibration(estimate=False)
    euler_correction: EulerCorrection = EulerCorrection()


class Arcs(StrictModel):
    """Arcs split where the epoch spacing departs from the nominal (median) step by more than
    ``spacing_tolerance`` (relative); arcs shorter than ``min_epochs`` are skipped."""

    spacing_tolerance: Annotated[float, Field(gt=0.0, lt=0.5)] = 0.01
    min_epochs: Annotated[int, Field(ge=3)] = 10


class DataConfig(StrictModel):
    """Input checks: a quaternion whose norm differs from 1 by more than the tolerance is
    refused; SCA and ACC epochs closer than ``time_match_tolerance_s`` are one epoch."""

    quaternion_norm_tolerance: PositiveFloat = 1.0e-5
    time_match_tolerance_s: PositiveFloat = 1.0e-5
    # the least share of each file's time span the other must cover (qkf.sca_fusion.data
    # check_pair): below half, most of the output would rest on one instrument alone
    min_overlap_fraction: Annotated[float, Field(gt=0.0, le=1.0)] = 0.5


class Oscillation(StrictModel):
    """Attitude motion about the orbit-following frame, per axis: ``count`` sinusoids of
    amplitude ``amplitude_urad`` with periods log-uniform in [period_min_s, period_max_s] and
    uniform phases (drawn from the seed)."""

    count: Annotated[int, Field(ge=0, le=100)] = 6
    amplitude_urad: NonNegativeFloat = 100.0
    period_min_s: PositiveFloat = 60.0
    period_max_s: PositiveFloat = 3000.0

    @model_validator(mode="after")
    def _ordered(self) -> Oscillation:
        if self.period_max_s < self.period_min_s:
            raise ValueError("period_max_s must be at least period_min_s")
        return self


class Outliers(StrictModel):
    """Star-camera outliers: a fraction of the epochs get ``size_sigma`` noise sigmas added on
    every axis (random signs)."""

    fraction: Annotated[float, Field(ge=0.0, le=0.5)] = 0.0
    size_sigma: NonNegativeFloat = 10.0


MAX_EPOCHS = 2_000_000


class Simulation(StrictModel):
    """The simulated arc used when no data files are given (docs/sca_fusion.md)."""

    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    duration_s: PositiveFloat = 10800.0
    dt_s: PositiveFloat = 1.0
    orbit_period_s: PositiveFloat = 5640.0
    oscillation: Oscillation = Oscillation()
    sca_noise_arcsec: PositiveVector3 = (2.0, 2.0, 2.0)
    acc_noise_rad_s2: PositiveVector3 = (1.0e-6, 2.0e-7, 2.0e-7)
    acc_bias_rad_s2: Vector3 = (3.0e-7, -2.0e-7, 1.0e-7)
    acc_scale: Vector3 = (0.0, 0.0, 0.0)
    proof_mass_inertia: PositiveVector3 = (1.037e-5, 1.959e-5, 1.037e-5)
    sca_outliers: Outliers = Outliers()
    sca_gaps: list[TimeWindow] = Field(default_factory=list)
    data_gaps: list[TimeWindow] = Field(default_factory=list)

    @model_validator(mode="after")
    def _fits(self) -> Simulation:
        if self.duration_s / self.dt_s > MAX_EPOCHS:
            raise ValueError(f"duration_s / dt_s: at most {MAX_EPOCHS:,} epochs")
        if self.duration_s < 3 * self.dt_s:
            raise ValueError("duration_s must cover at least 3 steps (dt_s)")
        return self


class FusionConfig(ProblemConfig):
    estimator: Estimator = Estimator()
    arcs: Arcs = Arcs()
    data: DataConfig = DataConfig()
    simulation: Simulation = Simulation()


PRESETS = "sca_fusion"
"""The problem's preset folder (``configs/sca_fusion/``)."""


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> FusionConfig:
    """Read and validate a fusion config (a path or a preset name such as ``sca_acc_fusion``)
    and apply ``--set`` overrides. Raises :class:`ConfigError` naming the file and the field."""
    return presets.load_preset(FusionConfig, path, PRESETS, overrides)


__all__ = ["ConfigError", "Estimator", "FusionConfig", "Simulation", "load_config"]
