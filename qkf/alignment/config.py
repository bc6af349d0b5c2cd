"""Configuration of the attitude-independent alignment calibration (docs/alignment.md).

Values carry their display unit in their name (``sigma_arcsec``, ``prior_deg``); the package
converts to SI (rad) once. The schema is strict; the machinery is :mod:`qkf.core.config`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from qkf.core import presets
from qkf.core.config import (
    ConfigError,
    NonNegativeFloat,
    PositiveFloat,
    ProblemConfig,
    StrictModel,
)

Vector3 = tuple[float, float, float]
SensorName = Annotated[str, Field(pattern=r"^[A-Za-z0-9_.+-]{1,64}$")]


def _nonzero(v: Vector3, what: str) -> None:
    """``ValueError`` for a direction that is the zero vector (no direction at all)."""
    if sum(c * c for c in v) < 1e-12:
        raise ValueError(f"{what} must not be the zero vector")


class Sensor(StrictModel):
    """A vector sensor: it reports unit vectors in the body frame through its nominal mounting.

    ``sigma_arcsec`` is the 1-σ noise per axis perpendicular to the reported vector;
    ``prior_deg`` the 1-σ prelaunch uncertainty of its alignment per body axis (default: the
    config's ``prior_deg``). The simulation and the report also use ``boresight`` (body frame),
    ``fov_deg`` (half-angle of the field of view), ``observes`` (catalogue ``stars`` anywhere in
    the field, or the ``sun``, a fixed inertial direction, when it is in the field),
    ``per_epoch`` (vectors reported per epoch at most) and ``misalignment_deg`` (the true
    alignment ``θ`` of the simulation, rad in the model; ``null``: drawn from the prior).
    """

    name: SensorName
    sigma_arcsec: PositiveFloat
    prior_deg: PositiveFloat | None = None
    boresight: Vector3 = (0.0, 0.0, 1.0)
    fov_deg: Annotated[float, Field(ge=0.0, le=180.0)] = 8.0
    observes: Literal["stars", "sun"] = "stars"
    per_epoch: Annotated[int, Field(ge=1, le=100)] = 1
    misalignment_deg: Vector3 | None = None

    @model_validator(mode="after")
    def _boresight(self) -> Sensor:
        _nonzero(self.boresight, "boresight")
        return self


class Solver(StrictModel):
    """Gauss–Newton: stop when every component of the step is below ``tolerance`` times its
    standard deviation, or after ``max_iterations``. ``correlated_pairs``: weight the pairs of an
    epoch with their full covariance (pairs sharing an observation are correlated); ``false``
    weights each pair with its own variance only, for comparison."""

    max_iterations: Annotated[int, Field(ge=1, le=1000)] = 20
    tolerance: PositiveFloat = 1.0e-3
    correlated_pairs: bool = True


class Observability(StrictModel):
    """Directions of the alignment space that the data do not determine.

    With the data information scaled by the prior sigmas, a direction whose eigenvalue is below
    ``rank_tolerance`` times the largest counts as rank-deficient, and one where the prior
    supplies more than ``prior_share`` of the posterior information as prior-determined."""

    rank_tolerance: Annotated[float, Field(gt=0.0, lt=1.0)] = 1.0e-6
    prior_share: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.5


class DataChecks(StrictModel):
    """Input checks: a vector whose norm differs from 1 by more than ``unit_tolerance`` is
    refused; observations closer in time than ``time_tolerance_s`` belong to one epoch."""

    unit_tolerance: PositiveFloat = 1.0e-6
    time_tolerance_s: NonNegativeFloat = 1.0e-6


MAX_EPOCHS = 1_000_000


class Simulation(StrictModel):
    """The data simulated when no ``--data`` is given: ``epochs`` epochs ``dt_s`` apart, an
    attitude drawn uniformly over the rotations at every epoch, ``sun_direction`` in the
    inertial frame."""

    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    epochs: Annotated[int, Field(ge=1, le=MAX_EPOCHS)] = 400
    dt_s: PositiveFloat = 10.0
    attitude: Literal["random"] = "random"
    sun_direction: Vector3 = (1.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _sun(self) -> Simulation:
        _nonzero(self.sun_direction, "sun_direction")
        return self


class AlignmentConfig(ProblemConfig):
    reference: SensorName
    prior_deg: PositiveFloat = 0.5
    sensors: Annotated[list[Sensor], Field(min_length=2)]
    solver: Solver = Solver()
    observability: Observability = Observability()
    data: DataChecks = DataChecks()
    simulation: Simulation = Simulation()

    @model_validator(mode="after")
    def _sensors(self) -> AlignmentConfig:
        names = [s.name for s in self.sensors]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"sensor names must be unique: {', '.join(dup)}")
        if self.reference not in names:
            raise ValueError(f"reference {self.reference!r} is not a sensor ({', '.join(names)})")
        ref = self.sensors[names.index(self.reference)]
        if ref.misalignment_deg is not None and any(v != 0.0 for v in ref.misalignment_deg):
            raise ValueError(
                f"sensor {ref.name!r} is the reference: it defines the body frame, so its "
                "misalignment_deg must be zero or absent"
            )
        return self

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.sensors]

    def prior_deg_of(self, sensor: Sensor) -> float:
        return sensor.prior_deg if sensor.prior_deg is not None else self.prior_deg


PRESETS = "alignment"
"""The problem's preset folder (``configs/alignment/``)."""


def load_config(
    path: str | Path | None = None, overrides: list[str] | None = None
) -> AlignmentConfig:
    """Read and validate an alignment config (a path or a preset name such as
    ``alignment_three_sensors``) and apply ``--set`` overrides. Raises :class:`ConfigError`."""
    return presets.load_preset(AlignmentConfig, path, PRESETS, overrides)


__all__ = ["AlignmentConfig", "ConfigError", "Sensor", "load_config"]
