"""Detection and calibration metrics (docs/redundant_gyros.md, "Metrics").

Detection metrics are counted per trial, so that intervals come from resampling trials:

* false-alarm rate: epochs flagged before the fault (from the first full window on) over the
  epochs counted there;
* missed detection: epochs not flagged after the fault (from the first full window after it
  on) over the epochs counted there;
* correct isolation: epochs, over the same post-fault epochs, that isolate the faulty gyro;
* detection delay: time from the fault to the first flagged epoch at or after it (a trial that
  never detects has none and is counted in ``never``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from qkf.core.stats import percentile_interval
from qkf.core.units import DEG
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.threecross import NO_GYRO

DETECTION_METRICS = ("false_alarm_rate", "missed_detection", "correct_isolation", "delay_s")


@dataclass(frozen=True)
class TrialCounts:
    """Per-trial counts of one detector (arrays of length B)."""

    pre_epochs: np.ndarray
    false_alarms: np.ndarray
    post_epochs: np.ndarray
    detected: np.ndarray
    correct: np.ndarray
    delay_s: np.ndarray  # NaN: never detected

    @staticmethod
    def concat(parts: list[TrialCounts]) -> TrialCounts:
        return TrialCounts(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in TrialCounts.FIELDS)
        )

    FIELDS = ("pre_epochs", "false_alarms", "post_epochs", "detected", "correct", "delay_s")


def count_trials(
    isolated: np.ndarray, faulty: int, fault_epoch: int, window: int, dt: float
) -> TrialCounts:
    """Counts of a detector's isolation results (B, E) for a fault of gyro ``faulty`` from epoch
    ``fault_epoch`` (E: no fault). Epochs before the detector's first full window, and the
    first ``window − 1`` epochs after the fault, are not counted."""
    flagged = isolated != NO_GYRO
    b, e = isolated.shape
    pre = slice(min(window - 1, fault_epoch), fault_epoch)
    post = slice(min(fault_epoch + window - 1, e), e)
    after = flagged[:, fault_epoch:]
    first = np.argmax(after, axis=1).astype(float)
    first[~after.any(axis=1)] = np.nan
    return TrialCounts(
        pre_epochs=np.full(b, pre.stop - pre.start, dtype=float),
        false_alarms=flagged[:, pre].sum(axis=1).astype(float),
        post_epochs=np.full(b, post.stop - post.start, dtype=float),
        detected=flagged[:, post].sum(axis=1).astype(float),
        correct=(isolated[:, post] == faulty).sum(axis=1).astype(float),
        delay_s=first * dt,
    )


@dataclass(frozen=True)
class Estimate:
    value: float
    lo: float
    hi: float


def _ratio(num: np.ndarray, den: np.ndarray, counts: np.ndarray, level: float) -> Estimate:
    total = float(den.sum())
    value = float(num.sum()) / total if total > 0 else float("nan")
    with np.errstate(invalid="ignore", divide="ignore"):
        boot = (counts @ num) / (counts @ den)
    boot = boot[np.isfinite(boot)]
    if boot.size == 0:
        return Estimate(value, float("nan"), float("nan"))
    lo, hi = percentile_interval(boot, level)
    return Estimate(value, float(lo), float(hi))


def summarize_counts(c: TrialCounts, counts: np.ndarray, level: float) -> dict[str, Estimate]:
    """The four detection metrics with percentile-bootstrap intervals over trials; ``counts``
    from :func:`qkf.core.stats.resample_counts`."""
    found = np.isfinite(c.delay_s)
    return {
        "false_alarm_rate": _ratio(c.false_alarms, c.pre_epochs, counts, level),
        "missed_detection": _ratio(c.post_epochs - c.detected, c.post_epochs, counts, level),
        "correct_isolation": _ratio(c.correct, c.post_epochs, counts, level),
        "delay_s": _ratio(np.where(found, c.delay_s, 0.0), found.astype(float), counts, level),
    }


def nees_band(dof: int, trials: int, level: float) -> tuple[float, float]:
    """Two-sided band of the mean NEES over ``trials`` consistent trials (χ²(dof · trials) /
    trials)."""
    tail = (1.0 - level) / 2.0
    lo, hi = stats.chi2.ppf([tail, 1.0 - tail], dof * trials) / trials
    return float(lo), float(hi)


def convergence_tolerance(cfg: GyrosConfig) -> np.ndarray:
    """``calibration.converged_within`` in internal units [b deg/s, λ, δ_u rad, δ_v rad]."""
    tol = cfg.calibration.converged_within
    return np.array([tol.bias_deg_s, tol.scale, tol.delta_deg * DEG, tol.delta_deg * DEG])


def convergence_step(err: np.ndarray, tolerance: np.ndarray) -> int | None:
    """First step from which every |error| (K, 4) stays within ``tolerance`` (4,) to the end;
    None if it never settles."""
    inside = np.all(np.abs(err) <= tolerance, axis=1)
    if not inside[-1]:
        return None
    outside = np.flatnonzero(~inside)
    return 0 if outside.size == 0 else int(outside[-1] + 1)
