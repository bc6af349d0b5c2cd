"""Fixed-Q filters: the nominal κ (``run.kappa``) and the tuned constant κ (docs/methods.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.core.montecarlo import progress_stage
from qkf.transfer_alignment.adaptive import TunedConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.judging import estimate_scores, pooled
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    action_values,
    new_filter,
    uses_settings,
    with_epoch_records,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder, step_recording
from qkf.transfer_alignment.scenario import ScenarioData, simulate


def run_fixed(cfg: Config, data: ScenarioData, kappa: float) -> MethodOutput:
    """The transfer-alignment KF with a constant process-noise factor ``κ``."""
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    rec = step_recording(kf, data, 0, data.n_epochs, kappa, cov)
    out = MethodOutput(est=rec.est, diverged=kf.diverged.copy(), cov=cov.cov)
    return with_epoch_records(out, rec)


def run_kf(cfg: Config, data: ScenarioData) -> MethodOutput:
    """Fixed-Q KF: κ = ``run.kappa`` (1 by default)."""
    return run_fixed(cfg, data, cfg.run.kappa)


def tuned_kappa(
    cfg: Config, progress_label: str = "tune kf-tuned"
) -> tuple[float, tuple[float, ...]]:
    """The action whose constant κ gives the lowest ``adaptive.tuned.metric`` (settled window,
    RMS over trials; :mod:`..judging`) on the tuning trials (seed ``adaptive.tuned.seed``, a
    range disjoint from every judging seed).

    Returns ``(κ*, score per action)`` (the metric's own units: dimensionless for
    ``state_settled``, SI for a group). ``progress_label``: the progress row it shows while a
    benchmark's progress bar is open (:func:`qkf.core.montecarlo.progress_stage`).
    """
    tc = cfg.adaptive.tuned
    kappas = action_values(cfg)
    # its own row under the benchmark's progress bar: tuning runs before any trial and takes
    # a while (one filter run over the tuning trials per action)
    advance = progress_stage(progress_label, len(kappas), "tuning runs")
    data = simulate(cfg, tc.seed, tc.trials)
    scores = []
    for kappa in kappas:
        out = run_fixed(cfg, data, float(kappa))
        scores.append(pooled(estimate_scores(cfg, out.est, data, tc.metric), out.diverged))
        advance(1)
    best = int(np.argmin(scores))
    return float(kappas[best]), tuple(scores)


@dataclass(frozen=True)
class FixedKappa:
    """A fixed-Q KF with a κ chosen beforehand (what :class:`TunedKF` prepares)."""

    kappa: float
    note: str = ""

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        out = run_fixed(cfg, data, self.kappa)
        if self.note:
            out.notes["kf-tuned"] = self.note
        return out


@uses_settings("tuned", TunedConfig)
class TunedKF:
    """Tuned fixed-Q KF: the best constant κ of the action set, picked on tuning seeds.

    The tuning runs once per benchmark, in :meth:`prepare` (driver process); calling the
    method unprepared tunes on the spot.
    """

    def prepare(self, cfg: Config) -> FixedKappa:
        kappa, _ = tuned_kappa(cfg)
        n = cfg.adaptive.tuned.trials
        return FixedKappa(kappa, f"κ = {kappa:.3g} (best constant κ on {n} tuning trials)")

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return self.prepare(cfg)(cfg, data)


run_kf_tuned = TunedKF()
