r"""The NIS rule: a burst of process noise after any innovation alarm (docs/methods.md, "NIS
rule").

The filter runs in decision periods of ``adaptive.nis_rule.period_s``. After each period::

    x = mean over the period's measurement epochs of νᵀS⁻¹ν / m      (NIS per row, 1 if none)
    a ← 0 if x > nis_threshold, else a + period                     (time since the last alarm)
    κ(next period) = κ_burst  if a < hold_s,  else κ_base

Three numbers (κ_base, κ_burst, hold_s; the threshold a fourth) and no memory of changes: the
simplest rule that mimics a learned policy that bursts after surprises. It is
:class:`~qkf.transfer_alignment.alarms.ChangeClock` with no quiet time (every alarm restarts
the burst). Its settings are tuned like every other baseline's (``nis-rule-tuned``).
"""

from __future__ import annotations

import numpy as np

from qkf.transfer_alignment.adaptive import NisRuleConfig
from qkf.transfer_alignment.alarms import ChangeClock
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.alarm_burst import run_periodic_rule
from qkf.transfer_alignment.methods.base import MethodOutput, uses_settings
from qkf.transfer_alignment.scenario import ScenarioData


class NisRuleDecision:
    """The rule's decision for N runs, one period at a time: ``reset(rows)`` starts runs anew,
    ``__call__(x, period_s)`` returns the next period's κ (N,) from the period's mean NIS per
    row ``x`` (N,). What the method runs, and the ``base="nis-rule"`` of the environments'
    residual controls (docs/environment.md, "Controls")."""

    def __init__(self, settings: NisRuleConfig, n: int) -> None:
        self.settings = settings
        self.clock = ChangeClock(n, quiet_s=0.0, nis_alarm=settings.nis_threshold)

    def reset(self, rows: np.ndarray) -> None:
        self.clock.reset(rows)

    def __call__(self, nis: np.ndarray, period_s: np.ndarray | float) -> np.ndarray:
        nr = self.settings
        since = self.clock.update(self.clock.alarms(nis), period_s)
        return np.where(since < nr.hold_s - 1e-9, nr.kappa_burst, nr.kappa_base)


@uses_settings("nis_rule", NisRuleConfig)
class NisRule:
    """The ``nis-rule`` method (module docstring)."""

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        nr = cfg.adaptive.nis_rule
        decide = NisRuleDecision(nr, data.n_trials)
        out = run_periodic_rule(cfg, data, nr.period_s, nr.kappa_base, decide)
        out.notes["nis-rule"] = (
            f"κ = {nr.kappa_burst:.3g} for {nr.hold_s:g} s after any period with NIS per row > "
            f"{nr.nis_threshold:g}, else {nr.kappa_base:.3g}"
        )
        return out


run_nis_rule = NisRule()
