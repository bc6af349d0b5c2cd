"""The κ action set that adaptive filters and agents choose from (every problem shares it)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, PositiveFloat

from qkf.core.config import StrictModel


class ActionSet(StrictModel):
    """The process-noise factors κ_i = 10^(log10_min + i · log10_step), i = 0 … count − 1."""

    log10_min: float = -2.0
    log10_step: PositiveFloat = 0.4
    count: Annotated[int, Field(ge=2, le=101)] = 11

    def values(self) -> list[float]:
        """The factors κ_i, ascending."""
        return [10.0 ** (self.log10_min + i * self.log10_step) for i in range(self.count)]

    def nominal_index(self) -> int:
        """Index of the action closest to κ = 1 (where adaptive methods and episodes start)."""
        return min(range(self.count), key=lambda i: abs(self.log10_min + i * self.log10_step))
