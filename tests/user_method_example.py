"""A user's method with one setting, as docs/architecture.md ("Recipe: add a method") shows it.

It lives in an importable module (not a script) so that every backend runs it: process-pool and
Ray workers import it by name. ``qkf bench paper --set adaptive.mine.gain=2 --methods
kf,mine=tests.user_method_example:run_mine`` (or ``adaptive: {mine: {gain: 2}}`` in the YAML)
runs the fixed-Q filter with κ = 2 throughout, which ``kappa.csv`` shows:
tests/test_method_settings.py checks that the setting reaches the method under every backend.
"""

from __future__ import annotations

import numpy as np

from qkf.core.config import PositiveFloat, StrictModel
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    method_settings,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.scenario import ScenarioData


class MineSettings(StrictModel):
    """``adaptive.mine``: the method's settings, defaults and validation in one place."""

    gain: PositiveFloat = 1.0  # the constant κ the filter uses


@uses_settings("mine", MineSettings)
def run_mine(cfg: Config, data: ScenarioData) -> MethodOutput:
    """The fixed-Q KF with κ = ``adaptive.mine.gain`` at every epoch, reporting that κ."""
    settings = method_settings(cfg, "mine", MineSettings)
    kf = new_filter(cfg, data)
    rec = kf.step_data(data, 0, data.n_epochs, kappa=settings.gain)
    kappa = np.full((data.n_trials, data.n_epochs), settings.gain)
    return MethodOutput(est=rec.est, diverged=kf.diverged.copy(), kappa=kappa)
