r"""Alarm burst: the oracle's schedule, started by an innovation alarm instead of the truth.

A classical detect-and-reopen rule (docs/methods.md, "Alarm burst"). The filter runs in
decision periods of ``adaptive.alarm_burst.period_s``. After each period,

    x = mean over the period's measurement epochs of νᵀS⁻¹ν / m      (NIS per row, 1 if none)
    alarm  ⇔  x > nis_alarm
    a ← 0 at an alarm after ≥ quiet_s without one, else a + period   (age of the change)
    κ(next period) = κ_after  if a < W,  else κ_base

(:class:`qkf.transfer_alignment.alarms.ChangeClock`). ``(κ_base, κ_after, W)`` are the
oracle's, tuned with the truth on the tuning seeds (:func:`tune_oracle`), just as ``kf-tuned``
is tuned: the only difference to the oracle is *when* the window starts, so
``oracle − alarm-burst`` measures what detection costs. Without a jump in the tuning
scenario the oracle's window is empty and this is the tuned constant κ.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.adaptive import AlarmBurstConfig
from qkf.transfer_alignment.alarms import change_clock
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    EpochRecords,
    MethodOutput,
    new_filter,
    per_epoch,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder, step_recording
from qkf.transfer_alignment.methods.oracle import OracleSchedule, tune_oracle
from qkf.transfer_alignment.scenario import ScenarioData


def nis_per_row(nis: np.ndarray, n_meas: int) -> np.ndarray:
    """Mean over a period's epochs (B, P) of the NIS per measurement row; 1 (no evidence)
    where the period had no finite NIS."""
    ok = np.isfinite(nis)
    n = ok.sum(axis=1)
    total = np.where(ok, nis, 0.0).sum(axis=1)
    return np.where(n > 0, total / np.maximum(n, 1) / n_meas, 1.0)


Decide = Callable[[np.ndarray, float], np.ndarray]
"""A periodic rule's decision: the next period's κ (B,) from the period's mean NIS per row
(B,) and its length in seconds."""


def run_periodic_rule(
    cfg: Config, data: ScenarioData, period_s: float, kappa0: float, decide: Decide
) -> MethodOutput:
    """The filter run in decision periods of ``period_s``: κ held over each period (``kappa0``
    over the first), the next one decided from the period's mean NIS per row
    (:func:`nis_per_row`). Shared by ``alarm-burst`` and ``nis-rule``."""
    period = max(1, round(period_s / cfg.scenario.dt_s))
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    kappa = np.full(data.n_trials, kappa0)
    est, held = [], []
    epochs = EpochRecords(data.n_trials, data.n_epochs)
    for k0 in range(0, data.n_epochs, period):
        k1 = min(data.n_epochs, k0 + period)
        rec = step_recording(kf, data, k0, k1, kappa, cov)
        est.append(rec.est)
        epochs.put(k0, rec)
        held.append(kappa)
        kappa = decide(nis_per_row(rec.nis, kf.params.n_meas), (k1 - k0) * cfg.scenario.dt_s)
    out = MethodOutput(
        est=np.concatenate(est, axis=1),
        diverged=kf.diverged.copy(),
        kappa=per_epoch(np.stack(held, axis=1), period, data.n_epochs),
        cov=cov.cov,
    )
    return epochs.attach(out)


@dataclass(frozen=True)
class AlarmBurstSchedule:
    """The rule with the oracle's parameters fixed (what :class:`AlarmBurst` prepares)."""

    schedule: OracleSchedule

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        ab, orc = cfg.adaptive.alarm_burst, self.schedule
        clock = change_clock(ab, data.n_trials)  # the alarm settings observation v2 sees too

        def decide(nis: np.ndarray, period_s: float) -> np.ndarray:
            age = clock.update(clock.alarms(nis), period_s)
            return np.where(age < orc.window_s - 1e-9, orc.after, orc.base)

        out = run_periodic_rule(cfg, data, ab.period_s, orc.base, decide)
        out.notes["alarm-burst"] = (
            f"κ = {orc.after:.3g} for {orc.window_s:g} s from the first NIS alarm of a change, "
            f"else {orc.base:.3g} (the oracle's values, tuned with the truth on tuning seeds)"
        )
        return out


@uses_settings("alarm_burst", AlarmBurstConfig, reads=("oracle", "tuned"))
class AlarmBurst:
    """The ``alarm-burst`` method: tuned once per benchmark in :meth:`prepare`."""

    def prepare(self, cfg: Config) -> AlarmBurstSchedule:
        return AlarmBurstSchedule(tune_oracle(cfg, progress_label="tune alarm-burst"))

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return self.prepare(cfg)(cfg, data)


run_alarm_burst = AlarmBurst()
