"""Innovation alarms and the age of a calibration change, as a flight computer can see them.

Shared by the ``alarm-burst`` method (docs/methods.md, "Alarm burst") and the environment's
observation v2 (docs/environment.md, "Observation v2"), so that both see the same change.

A decision period *alarms* when its mean NIS per measurement row exceeds :data:`NIS_ALARM`. A
*change* starts at an alarm that follows at least :data:`QUIET_S` without one; the alarms that
follow it sooner belong to the same change. Its *age* is the time since it started.
"""

from __future__ import annotations

import numpy as np

NIS_ALARM = 4.0
"""A period whose mean NIS per measurement row exceeds this is an alarm. Under a consistent
filter the 10-epoch mean of χ²/m has mean 1 and standard deviation ≈ 0.2–0.3, so a chance
alarm is a > 10σ event; a calibration jump seen during a rotation gives 10 … 100."""

QUIET_S = 600.0
"""An alarm after at least this long without one starts a new change. A calibration change
raises an alarm at each rotation axis that makes part of it observable (60–150 s apart in the
thermal scenarios): 600 s is longer than a three-axis rotation sequence, and shorter than the
time between calibration events of the thermal scenarios."""


class ChangeClock:
    """Per-row clocks of N runs: time since the last alarm and age of the current change (s;
    ∞ before the first alarm)."""

    def __init__(self, n: int, quiet_s: float = QUIET_S) -> None:
        self.quiet_s = quiet_s
        self.quiet = np.full(n, np.inf)
        self.age = np.full(n, np.inf)

    def reset(self, rows: np.ndarray) -> None:
        """Restart the clocks of ``rows`` (no alarm seen yet)."""
        self.quiet[rows] = np.inf
        self.age[rows] = np.inf

    def update(self, alarm: np.ndarray, period_s: np.ndarray | float) -> np.ndarray:
        """Advance by one period of ``period_s`` seconds that alarmed where ``alarm`` (N,) is
        true; returns the age of the current change at the end of the period (N,), s."""
        onset = alarm & (self.quiet >= self.quiet_s)
        self.age = np.where(onset, 0.0, self.age + period_s)
        self.quiet = np.where(alarm, 0.0, self.quiet + period_s)
        return self.age
