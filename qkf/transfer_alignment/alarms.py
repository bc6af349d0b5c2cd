"""Innovation alarms and the age of a calibration change, as a flight computer can see them.

Shared by the ``alarm-burst`` method (docs/methods.md, "Alarm burst") and the environment's
observation v2 (docs/environment.md, "Observation v2"), so that both see the same change: both
build their clock with :func:`change_clock` from the same configured settings,
``adaptive.alarm_burst.nis_alarm`` and ``quiet_s`` (defaults and meaning:
:class:`~qkf.transfer_alignment.adaptive.AlarmBurstConfig`).

A decision period *alarms* when its mean NIS per measurement row exceeds ``nis_alarm``. A
*change* starts at an alarm that follows at least ``quiet_s`` without one; the alarms that
follow it sooner belong to the same change. Its *age* is the time since it started.
"""

from __future__ import annotations

import numpy as np

from qkf.transfer_alignment.adaptive import AlarmBurstConfig

_DEFAULTS = AlarmBurstConfig()

NIS_ALARM: float = _DEFAULTS.nis_alarm
"""The default of ``adaptive.alarm_burst.nis_alarm`` (read from the config section, its one
home). Code that has a config uses the configured value: :func:`change_clock`."""

QUIET_S: float = _DEFAULTS.quiet_s
"""The default of ``adaptive.alarm_burst.quiet_s`` (read from the config section, its one
home). Code that has a config uses the configured value: :func:`change_clock`."""


class ChangeClock:
    """Per-row clocks of N runs: time since the last alarm and age of the current change (s;
    ∞ before the first alarm). ``nis_alarm``: the threshold of :meth:`alarms`; ``quiet_s``: the
    calm after which an alarm starts a new change."""

    def __init__(self, n: int, quiet_s: float = QUIET_S, nis_alarm: float = NIS_ALARM) -> None:
        self.quiet_s = quiet_s
        self.nis_alarm = nis_alarm
        self.quiet = np.full(n, np.inf)
        self.age = np.full(n, np.inf)

    def alarms(self, nis_per_row: np.ndarray) -> np.ndarray:
        """Which of N periods alarmed, from their mean NIS per measurement row (N,)."""
        return np.asarray(nis_per_row > self.nis_alarm)

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


def change_clock(settings: AlarmBurstConfig, n: int) -> ChangeClock:
    """The clock of N runs with the alarm-burst method's alarm settings (``nis_alarm``,
    ``quiet_s``): what the ``alarm-burst`` method and the environment's observation v2 both use
    (the latter reads them through the method's declaration), so that a changed setting changes
    both alike."""
    return ChangeClock(n, quiet_s=settings.quiet_s, nis_alarm=settings.nis_alarm)
