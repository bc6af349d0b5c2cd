"""What a method returns, and the small helpers the methods share."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.scenario import ScenarioData


@dataclass
class MethodOutput:
    """A method's estimates for B trials over N epochs (SI)."""

    est: np.ndarray  # (B, N, 16): q̂ (scalar-last), b̂, p̂ after each epoch's update
    diverged: np.ndarray  # (B,) bool
    extras: dict[str, np.ndarray] = field(default_factory=dict)  # method-specific logs
    notes: dict[str, str] = field(default_factory=dict)  # one-line facts for the summary


def new_filter(cfg: Config, data: ScenarioData, n_copies: int = 1) -> TransferAlignmentKF:
    """A filter over ``n_copies`` × B trials (copies of a trial are adjacent), initialised."""
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), data.n_trials * n_copies)
    kf.initialize(np.repeat(data.ads_q[:, 0], n_copies, axis=0))
    return kf


def action_values(cfg: Config) -> np.ndarray:
    """The κ action set of the config."""
    return np.asarray(cfg.adaptive.actions.values())


def nominal_action(cfg: Config) -> int:
    """Index of the action closest to κ = 1 (where adaptive methods and episodes start)."""
    return int(np.argmin(np.abs(np.log(action_values(cfg)))))


def decision_period(cfg: Config) -> int:
    """Filter epochs per decision period ``T_c`` (at least one)."""
    return max(1, round(cfg.adaptive.qkf.period_s / cfg.scenario.dt_s))


def method_rng(data: ScenarioData, trial_row: int, stream: int) -> np.random.Generator:
    """A generator for one trial's own draws by a method, independent of batch and chunking."""
    return np.random.default_rng([data.seed, int(data.trial_ids[trial_row]), 0x9E3779B9, stream])
