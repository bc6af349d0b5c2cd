"""What each tunable baseline spends on its tuning (docs/methods.md, "Tuned baselines"): how
many settings it evaluates, each on ``adaptive.tuned.trials`` tuning trials.

Every tuned baseline gets the same budget: the Optuna variants ``adaptive.optuna.evaluations``
settings (50); ``kf-tuned`` every κ of the action set (its whole search space, 11 by
default: more evaluations could not find anything better); ``clock`` and ``alarm-burst`` the
runs of their coordinate searches (``A + passes · T · (A − 1)`` and ``A + 1 + (A − 1) · W``,
both above 50 with the defaults). All of them on the same ``adaptive.tuned.trials`` (16) trials
of the tuning seed. The ``-mixed`` variants spend what their base spends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from qkf.transfer_alignment.adaptive import ClockConfig, OptunaConfig, OracleConfig, TunedConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import action_values, settings_of
from qkf.transfer_alignment.methods.clock import run_clock
from qkf.transfer_alignment.methods.fixed import run_kf_tuned
from qkf.transfer_alignment.methods.on_mixture import MIXED_SUFFIX
from qkf.transfer_alignment.methods.oracle import run_oracle
from qkf.transfer_alignment.methods.tuned import TUNED_METHODS


@dataclass(frozen=True)
class Budget:
    """A tuned method's budget: ``evaluations`` settings, each on ``trials`` tuning trials;
    ``exhaustive``: the evaluations cover the method's whole search space."""

    evaluations: int
    trials: int
    exhaustive: bool = False


def _oracle_runs(cfg: Config) -> int:
    a = len(action_values(cfg))
    windows = settings_of(run_oracle, cfg, OracleConfig).windows_s
    return a + 1 + (a - 1) * len(windows)  # with a jump in the scenario


def tuning_budgets(cfg: Config) -> dict[str, Budget]:
    """The budget of every tunable method under ``cfg`` (module docstring), by name."""
    a = len(action_values(cfg))
    trials = settings_of(run_kf_tuned, cfg, TunedConfig).trials
    cc = settings_of(run_clock, cfg, ClockConfig)
    blocks = math.ceil(cfg.scenario.duration_s / cc.block_s)
    out = {
        "kf-tuned": Budget(a, trials, exhaustive=True),
        "clock": Budget(a + cc.passes * blocks * (a - 1), trials),
        "alarm-burst": Budget(_oracle_runs(cfg), trials),
    }
    for name in TUNED_METHODS:
        extra = _oracle_runs(cfg) if name == "alarm-burst-tuned" else 0
        evaluations = settings_of(TUNED_METHODS[name], cfg, OptunaConfig).evaluations
        out[name] = Budget(evaluations + extra, trials)
    out |= {name + MIXED_SUFFIX: budget for name, budget in list(out.items())}
    return out
