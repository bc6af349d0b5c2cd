"""The toy problem's schema (display units: u for the walked quantity, s) and its loader."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field, model_validator

from qkf.core import presets
from qkf.core.config import PositiveFloat, ProblemConfig, StrictModel

PRESETS = "toy_estimation"
"""The problem's preset folder in the preset tree (``configs/toy_estimation/``)."""
MAX_EPOCHS = 1_000_000
"""Upper bound on ``duration_s / dt_s`` (a typo such as 1e30 would exhaust memory)."""


class Walk(StrictModel):
    """The truth, the readings and what the filter assumes about them."""

    duration_s: PositiveFloat = 100.0
    dt_s: PositiveFloat = 1.0
    walk_u_per_sqrt_s: PositiveFloat = 0.1  # sd of x(t + dt) − x(t) is this · √dt
    noise_u: PositiveFloat = 1.0  # sd of one reading
    prior_sd_u: PositiveFloat = 10.0  # sd of x(0) about 0, known to the filter
    # the filter's reading sd (None: the true one); kept apart from the truth, as in every
    # problem, so that a mis-tuned filter can be judged by its NEES
    assumed_noise_u: PositiveFloat | None = None

    @model_validator(mode="after")
    def _epochs(self) -> Walk:
        if not 2 <= round(self.duration_s / self.dt_s) <= MAX_EPOCHS:
            raise ValueError(f"duration_s / dt_s must be between 2 and {MAX_EPOCHS:,}")
        return self


class Bench(StrictModel):
    trials: Annotated[int, Field(ge=1, le=1_000_000)] = 200
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    chunk_trials: Annotated[int, Field(ge=1, le=1_000_000)] = 64
    level: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.99  # probability of the NEES band


class ToyConfig(ProblemConfig):
    walk: Walk = Walk()
    bench: Bench = Bench()


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> ToyConfig:
    """A path or a preset name of :data:`PRESETS`, then ``--set`` overrides; ``ConfigError``
    names the file and the field, or lists this problem's presets (and no other's)."""
    return presets.load_preset(ToyConfig, path, PRESETS, overrides)
