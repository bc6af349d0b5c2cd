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

from qkf.transfer_alignment.alarms import ChangeClock
from qkf.transfer_alignment.config import Config, NisRuleConfig
from qkf.transfer_alignment.methods.alarm_burst import run_periodic_rule
from qkf.transfer_alignment.methods.base import MethodOutput
from qkf.transfer_alignment.scenario import ScenarioData


class NisRule:
    """The ``nis-rule`` method (module docstring)."""

    settings_section = "nis_rule"  # the settings it declares (methods.base.uses_settings)
    settings = NisRuleConfig

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        nr = cfg.adaptive.nis_rule
        clock = ChangeClock(data.n_trials, quiet_s=0.0, nis_alarm=nr.nis_threshold)

        def decide(nis: np.ndarray, period_s: float) -> np.ndarray:
            since = clock.update(clock.alarms(nis), period_s)
            return np.where(since < nr.hold_s - 1e-9, nr.kappa_burst, nr.kappa_base)

        out = run_periodic_rule(cfg, data, nr.period_s, nr.kappa_base, decide)
        out.notes["nis-rule"] = (
            f"κ = {nr.kappa_burst:.3g} for {nr.hold_s:g} s after any period with NIS per row > "
            f"{nr.nis_threshold:g}, else {nr.kappa_base:.3g}"
        )
        return out


run_nis_rule = NisRule()
