r"""Oracle schedule: the best piecewise-constant κ around each trial's true calibration jump.

Not a flight method: it reads the truth (``ScenarioData.jump_t``) and is tuned with the truth.
It is the upper reference of the comparison tables (docs/methods.md, "Oracle schedule"): a
learned policy's share of the gap is ``(RMS_kf − RMS_policy) / (RMS_kf − RMS_oracle)``.

The schedule, per trial with jump time ``t_j``::

    κ(t) = κ_after   for t_j ≤ t < t_j + W
    κ(t) = κ_base    otherwise

``(κ_base, κ_after, W)`` are chosen on the tuning seeds (``adaptive.tuned``) by coordinate
search: ``κ_base`` as the best constant κ of the action set, then ``(κ_after, W)`` over the
action set × ``adaptive.oracle.windows_s``; the criterion is the settled-window RMS of
``adaptive.oracle.metric`` (``state_settled`` by default: :mod:`..judging`). Without a jump
(no ``jump_t``) the oracle is the tuned constant κ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.core.montecarlo import progress_stage
from qkf.transfer_alignment.adaptive import OracleConfig
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


def schedule(data: ScenarioData, base: float, after: float, window_s: float) -> np.ndarray:
    """κ per trial and epoch (B, N): ``after`` in ``[t_j, t_j + W)`` for every jump time
    ``t_j`` of the trial (``data.jumps_t``; windows that overlap merge), ``base`` elsewhere."""
    columns = [] if data.jump_t is None else [data.jump_t]
    if data.jumps_t is not None:
        # jump_t is jumps_t's first column in simulated data; both are read, so that data whose
        # jump_t alone was set by hand still opens its window there
        columns += list(data.jumps_t.T)
    t = data.t[None, :]
    inside = np.zeros((data.n_trials, data.n_epochs), dtype=bool)
    for jump in columns:  # NaN (no jump) compares false: no window
        inside |= (t >= jump[:, None] - 1e-9) & (t < jump[:, None] + window_s - 1e-9)
    return np.where(inside, after, base)


def run_schedule(cfg: Config, data: ScenarioData, kappa: np.ndarray) -> MethodOutput:
    """The transfer-alignment KF with a given κ per trial and epoch (B, N)."""
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    rec = step_recording(kf, data, 0, data.n_epochs, kappa, cov)
    out = MethodOutput(est=rec.est, diverged=kf.diverged.copy(), kappa=kappa, cov=cov.cov)
    return with_epoch_records(out, rec)


def settled_score(cfg: Config, data: ScenarioData, out: MethodOutput) -> float:
    """The tuning criterion: RMS over trials of ``adaptive.oracle.metric`` (settled window)."""
    scores = estimate_scores(cfg, out.est, data, cfg.adaptive.oracle.metric)
    return pooled(scores, out.diverged)


@dataclass(frozen=True)
class OracleSchedule:
    """The schedule with its parameters fixed (what :class:`Oracle` prepares)."""

    base: float
    after: float
    window_s: float

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        out = run_schedule(cfg, data, schedule(data, self.base, self.after, self.window_s))
        out.notes["oracle"] = (
            f"κ = {self.after:.3g} for {self.window_s:g} s after the true jump, else "
            f"{self.base:.3g} (tuned with the truth; an upper reference, not a flight method)"
        )
        return out


def tune_oracle(cfg: Config, progress_label: str = "tune oracle") -> OracleSchedule:
    """Coordinate search for ``(κ_base, κ_after, W)`` on the tuning seeds (module docstring).

    ``progress_label``: the progress row it shows, with its count of filter runs, while a
    benchmark's progress bar is open (:func:`qkf.core.montecarlo.progress_stage`).
    """
    tc = cfg.adaptive.tuned
    data = simulate(cfg, tc.seed, tc.trials)
    kappas = [float(k) for k in action_values(cfg)]
    n = data.n_epochs
    jumps = data.jump_t is not None and bool(np.isfinite(data.jump_t).any())
    # the count is known beforehand: every κ_base; with a jump, the constant κ_base once more
    # and every (κ_after ≠ κ_base, W)
    windows = len(cfg.adaptive.oracle.windows_s)
    runs = len(kappas) + (1 + (len(kappas) - 1) * windows if jumps else 0)
    advance = progress_stage(progress_label, runs, "tuning runs")

    def score(base: float, after: float, window: float) -> float:
        kap = schedule(data, base, after, window) if after != base else np.full((1, n), base)
        kap = np.broadcast_to(kap, (data.n_trials, n))
        value = settled_score(cfg, data, run_schedule(cfg, data, kap))
        advance(1)
        return value

    base = min(kappas, key=lambda k: score(k, k, 0.0))
    if not jumps:
        return OracleSchedule(base, base, 0.0)
    best = (score(base, base, 0.0), base, 0.0)
    for after in kappas:
        for window in cfg.adaptive.oracle.windows_s:
            if after != base:
                best = min(best, (score(base, after, window), after, window))
    return OracleSchedule(base, best[1], best[2])


@uses_settings("oracle", OracleConfig, reads=("tuned",))
class Oracle:
    """The ``oracle`` method: tuned once per benchmark in :meth:`prepare` (driver process)."""

    def prepare(self, cfg: Config) -> OracleSchedule:
        return tune_oracle(cfg)

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return self.prepare(cfg)(cfg, data)


run_oracle = Oracle()
