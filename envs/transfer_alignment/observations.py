r"""Observations of the transfer-alignment environments: a registry, one entry per env version
(docs/environment.md, "Observation").

An observation turns the filter's record of the decision period just run into one float32
vector per episode. Everything it reads is available on board: the filter's own covariance,
its innovations and their statistics, the rate it propagates with, the clock and the κ in use.
The truth never enters an observation (it may shape a reward in simulation, never what the
agent sees).

* ``v0`` (``qkf/TransferAlignment-v0``, 9 entries): the original observation, kept unchanged
  so that saved v0 policies act as they were trained.
* ``v1`` (``qkf/TransferAlignment-v1``, 12 entries): every entry of order one. The likelihood
  gain of v0 (≈ 1e-6 … 5e-4) is replaced by change-detection statistics of the innovations
  (log NIS, a windowed NIS, a CUSUM, the time since the last NIS alarm) and the rotation
  history (time since the rate last changed).
* ``v2`` (``qkf/TransferAlignment-v2``, 13 entries): v1 plus the age of the current change,
  the time since the first alarm of the present run of alarms. v1's time since the *last*
  alarm restarts at every alarm, and a calibration change raises one at every rotation axis
  that follows it, so a memoryless policy on v1 cannot tell a fresh change from an old one
  seen again (docs/environment.md, "Observation v2").
* ``v3`` (``qkf/TransferAlignment-v3``, 15 entries): the evidence of v2 without the clock. The
  elapsed fraction of the episode is gone (a policy that reads it can learn a schedule, not a
  reaction), the calibration covariance level is split into scale factor and misalignment, and
  the windowed NIS is given per block (attitude, rate) besides the whole.
* ``v4`` (``qkf/TransferAlignment-v4``, 24 entries): v3, slow evidence (NIS means over 300
  and 1000 s per block, a slow CUSUM) and the moves in use (process-noise factors of attitude
  and bias, the assumed ADS σ factor, the time since the last reset): what a policy needs to
  see a slow drift and to act with the moves of :mod:`envs.transfer_alignment.controls`.
* ``v3-time`` (``qkf/TransferAlignmentTimed-v3``, 16 entries): v3 and the elapsed fraction,
  the ablation that measures what the clock is worth.

An observation object is stateful over the N episodes of a batch: ``reset(rows, kappa_pos)``
starts episodes ``rows`` (returning their first observations), ``__call__(view)`` returns the
observations (N, size) after one period. Register your own with
``OBSERVATIONS.register(name, Observation(factory, size, description, needs_likelihood))``,
``factory(cfg, n, period_s)`` building it for the scenario's config, n episodes and the
decision period.

The NIS alarm of v1 and v2 (a period's mean NIS per row above ``adaptive.alarm_burst.nis_alarm``)
and v2's change clock (``quiet_s``) are those of the ``alarm-burst`` method: both come from
:func:`qkf.transfer_alignment.alarms.change_clock` with the scenario's config, so that a changed
setting (``--set adaptive.alarm_burst.nis_alarm=5``) changes the observation and the method
alike.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np

from envs.common.bounds import OBS_LIMIT, finite_clipped
from envs.transfer_alignment.period_summary import (
    EvidenceConstants,
    Summary,
    block_table,
    period_summary,
    update_evidence,
)
from qkf.core.registry import Registry
from qkf.transfer_alignment.adaptive import AlarmBurstConfig
from qkf.transfer_alignment.alarms import change_clock
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import FilterRecord
from qkf.transfer_alignment.methods.alarm_burst import run_alarm_burst
from qkf.transfer_alignment.methods.base import settings_of
from qkf.transfer_alignment.moves import Moves
from qkf.transfer_alignment.states import GROUPS

# The alarm threshold (v1, v2: a period's mean NIS per row above it is an alarm) and the calm
# that separates two changes (v2) are the config's adaptive.alarm_burst.nis_alarm and quiet_s,
# read through qkf.transfer_alignment.alarms.change_clock as the alarm-burst method reads them.

CUSUM_DRIFT = 1.0
"""v1: drift of the one-sided CUSUM ``S ← max(0, S + x − 1 − drift)`` of the period's mean
NIS per row ``x``: S decays by ≈ 1 per period under a consistent filter."""
NIS_WINDOW = 6
"""v1: periods in the windowed NIS (60 s at the default 10-s period)."""
RATE_CHANGE_DEG_S = 0.2
"""v1: a change of ω̂ between the ends of two periods larger than this (deg/s) marks a
manoeuvre starting, ending or changing axis: above the orbit rate of any Earth orbit
(≤ 0.07 deg/s) and its noise, below the rotation rates of attitude manoeuvres."""
TIME_SCALE_S = 10.0
"""v1: times since an event are shown as ``log10(1 + t / TIME_SCALE_S)`` (0 at the event,
1 after 90 s, 2 after 990 s)."""
ONSET_CAP_S = 1.0e4
"""v2: the age of the change is shown capped here (``log10(1 + 1000) = 3``), which is also
what is shown before the first alarm of an episode."""
LOG_FLOOR = 1e-2  # log10 of NIS statistics is floored here (−2)


@dataclass(frozen=True)
class PeriodView:
    """What an observation sees of one decision period of N episodes (SI units)."""

    record: FilterRecord  # the agent's filter over the period
    valid: np.ndarray  # (N, P) bool: epochs inside the episode
    last: np.ndarray  # (N,) index of the last valid epoch of the period
    steps: np.ndarray  # (N,) valid epochs (at least 1)
    loglik_gain: np.ndarray | None  # (N,) ℓ_agent − ℓ_nominal, if the observation asked for it
    elapsed: np.ndarray  # (N,) fraction of the episode done after the period
    kappa_pos: np.ndarray  # (N,) position of the κ in use on the action scale, 0 … 1
    p0_sigma: np.ndarray  # (15,) prior sigmas
    n_meas: int  # measurement rows per epoch (6 with rate matching, else 3)
    dt: float  # s
    moves: Moves | None = None  # v4: the moves in effect over the period (None: κ only)

    @cached_property
    def summary(self) -> Summary:
        """The period's NIS means, covariance levels of :data:`LEVEL_BLOCKS` and rate, in one
        compiled pass (:mod:`envs.transfer_alignment.period_summary`); computed once per view."""
        return period_summary(self.record, self.valid, self.last, self.p0_sigma, _LEVEL_TABLE)

    def nis_means(self, empty_att: float, empty_rate: float, empty_all: float) -> np.ndarray:
        """:func:`masked_mean` of the NIS att., NIS rate and NIS columns (N, 3), ``empty_*``
        where a row has no finite valid epoch."""
        sm = self.summary
        empty = np.array([empty_att, empty_rate, empty_all])
        return np.where(sm.nis_count > 0, sm.nis_mean, empty)


class ObservationState(Protocol):
    """The stateful observation of a batch of N episodes."""

    def reset(self, rows: np.ndarray, kappa_pos: float) -> np.ndarray:
        """Start episodes ``rows``; their first observations (len(rows), size)."""
        ...

    def __call__(self, view: PeriodView) -> np.ndarray:
        """Observations (N, size) after one period, float32, finite, within ±OBS_LIMIT."""
        ...


@dataclass(frozen=True)
class Observation:
    """An observation kind: ``factory(cfg, n, period_s)`` builds its state for a batch of n
    episodes of the scenario ``cfg`` with decision periods of ``period_s``."""

    factory: Callable[[Config, int, float], ObservationState]
    size: int
    description: str
    needs_likelihood: bool = False  # the κ = 1 shadow filter is run for the likelihood gain


OBSERVATIONS: Registry[Observation] = Registry("observation", group="qkf.observations")
"""Observation kinds by name (``observation=`` of the environments)."""


def masked_mean(x: np.ndarray, valid: np.ndarray, empty: float = 0.0) -> np.ndarray:
    """Row means over finite, valid entries; ``empty`` for a row without any."""
    ok = valid & np.isfinite(x)
    n = ok.sum(axis=1)
    return np.where(n > 0, np.where(ok, x, 0.0).sum(axis=1) / np.maximum(n, 1), empty)


THREE_BLOCKS = (slice(0, 3), slice(3, 6), slice(6, 15))
"""v0–v2: the attitude, bias and calibration blocks of the state."""
LEVEL_BLOCKS = (*THREE_BLOCKS, *GROUPS.values())
"""The blocks whose covariance levels :attr:`PeriodView.summary` computes: v0–v2's three,
then v3's four groups (attitude, bias, scale factor, misalignment)."""
_LEVEL_TABLE = block_table(LEVEL_BLOCKS)


def sigma_ratios(view: PeriodView, blocks: tuple[slice, ...] = THREE_BLOCKS) -> np.ndarray:
    """Mean ``log10(σ/σ₀)`` of each block of states at the period's last valid epoch
    (N, len(blocks)); v3 asks for the four groups (attitude, bias, scale factor,
    misalignment)."""
    rows = np.arange(view.last.size)
    log_ratio = 0.5 * np.log10(view.record.var[rows, view.last] / view.p0_sigma**2)
    return np.stack([log_ratio[:, sl].mean(axis=1) for sl in blocks], axis=1)


def rate_deg_s(view: PeriodView) -> np.ndarray:
    """ω̂ at the period's last valid epoch, deg/s (N, 3)."""
    rows = np.arange(view.last.size)
    return view.record.rate[rows, view.last] / (np.pi / 180.0)


class ObservationV0:
    """The 9-entry observation of ``qkf/TransferAlignment-v0`` (table in docs/environment.md)."""

    size = 9

    def __init__(self, cfg: Config, n: int, period_s: float) -> None:
        self.n = n

    def reset(self, rows: np.ndarray, kappa_pos: float) -> np.ndarray:
        obs = np.zeros((rows.size, self.size), dtype=np.float32)
        obs[:, 8] = kappa_pos
        return obs

    def __call__(self, view: PeriodView) -> np.ndarray:
        assert view.loglik_gain is not None
        sm = view.summary
        obs = np.empty((view.last.size, self.size))
        obs[:, 0:3] = sm.levels[:, 0:3]  # sigma_ratios(view)
        obs[:, 3:5] = view.nis_means(0.0, 0.0, 0.0)[:, 0:2] / 3.0
        obs[:, 5] = view.loglik_gain / (view.steps * view.n_meas)
        obs[:, 6] = view.elapsed
        obs[:, 7] = sm.rate_norm
        obs[:, 8] = view.kappa_pos
        return finite_clipped(obs)


class ObservationV1:
    """The 12-entry observation of ``qkf/TransferAlignment-v1``, every entry of order one.

    ====  ======================================================================  ============
    Obs   Meaning                                                                 Typical
    ====  ======================================================================  ============
    0–2   mean ``log10(σ/σ₀)`` of the attitude, bias, calibration blocks of P      −3.5 … 0
    3     ``log10`` of the period's mean attitude NIS / 3 (floor −2)               ≈ 0 ± 0.3
    4     ``log10`` of the period's mean rate NIS / 3 (0 without rate matching)    ≈ 0; ≤ 2 events
    5     ``log10`` of the mean NIS per row over the last ``NIS_WINDOW`` periods   ≈ 0
    6     ``log10(1 + S)``, S the CUSUM of the period's mean NIS per row           0; ≤ 2 events
    7     ``log10(1 + t/10 s)``, t the time since the last NIS alarm (or start)    0 … 2.6
    8     ``|ω̂|`` at the end of the period, deg/s                                  0.06 … 1.5
    9     ``log10(1 + t/10 s)``, t the time since ω̂ last changed (a manoeuvre)     0 … 2.6
    10    elapsed fraction of the episode                                          0 … 1
    11    position of the κ in use on the action scale                             0 … 1
    ====  ======================================================================  ============
    """

    size = 12

    def __init__(self, cfg: Config, n: int, period_s: float) -> None:
        self.period_s = period_s
        # the alarm (x > nis_alarm) and, for v2, the age of the change: the alarm-burst
        # method's clock with the same configured settings
        self.clock = change_clock(settings_of(run_alarm_burst, cfg, AlarmBurstConfig), n)
        self.alarm = np.zeros(n, dtype=bool)  # the last period's alarms (x > nis_alarm)
        self.cusum = np.zeros(n)
        # past periods' mean NIS per row, newest last: attitude, rate (v3) and all rows
        self.windows = np.ones((n, 3, NIS_WINDOW))
        self.window_logs = np.zeros((n, 3))  # log10 of their means (floor −2)
        self.since_alarm = np.zeros(n)  # s
        self.since_rate_change = np.zeros(n)  # s
        self.last_rate = np.full((n, 3), np.nan)  # deg/s; NaN: no period seen yet
        self.constants = EvidenceConstants(
            cusum_drift=CUSUM_DRIFT,
            nis_alarm=float(self.clock.nis_alarm),
            rate_change_deg_s=RATE_CHANGE_DEG_S,
            time_scale_s=TIME_SCALE_S,
            log_floor=LOG_FLOOR,
            obs_limit=OBS_LIMIT,
        )

    def reset(self, rows: np.ndarray, kappa_pos: float) -> np.ndarray:
        self.cusum[rows] = 0.0
        self.windows[rows] = 1.0
        self.since_alarm[rows] = 0.0
        self.since_rate_change[rows] = 0.0
        self.last_rate[rows] = np.nan
        obs = np.zeros((rows.size, ObservationV1.size), dtype=np.float32)
        obs[:, 11] = kappa_pos
        return obs

    def __call__(self, view: PeriodView) -> np.ndarray:
        return finite_clipped(self._values(view))

    def _evidence(self, view: PeriodView) -> tuple[Summary, np.ndarray]:
        """The period's summary, and the change-detection state advanced by one period (its
        :data:`~envs.transfer_alignment.period_summary.EVIDENCE_COLUMNS`), compiled: one call
        instead of some thirty numpy ones (docs/performance.md)."""
        sm = view.summary
        self.alarm, logs = update_evidence(
            sm, view.n_meas, view.steps * view.dt, self.constants, self.cusum, self.windows,
            self.since_alarm, self.since_rate_change, self.last_rate,
        )  # fmt: skip
        self.window_logs = logs[:, 2:5]
        return sm, logs

    def _values(self, view: PeriodView) -> np.ndarray:
        """The entries of the table (N, size), float64, before clipping."""
        sm, logs = self._evidence(view)
        obs = np.empty((logs.shape[0], ObservationV1.size))
        obs[:, 0:3] = sm.levels[:, 0:3]  # sigma_ratios(view)
        obs[:, 3:5] = logs[:, 0:2]  # log10 of the period's NIS per row, attitude and rate
        obs[:, 5] = logs[:, 4]  # the windowed NIS per row of all rows
        obs[:, 6:8] = logs[:, 5:7]  # CUSUM, time since the last alarm
        obs[:, 8] = sm.rate_norm
        obs[:, 9] = logs[:, 7]  # time since the rate changed
        obs[:, 10] = view.elapsed
        obs[:, 11] = view.kappa_pos
        return obs


class ObservationV2(ObservationV1):
    """The 13-entry observation of ``qkf/TransferAlignment-v2``: v1's twelve entries, then

    ====  ======================================================================  ============
    12    ``log10(1 + a/10 s)``, a the age of the current change: time since the    0 … 3
          first alarm after ≥ ``quiet_s`` without one (``ONSET_CAP_S`` if none)
    ====  ======================================================================  ============
    """

    size = 13

    def reset(self, rows: np.ndarray, kappa_pos: float) -> np.ndarray:
        first = super().reset(rows, kappa_pos)
        self.clock.reset(rows)
        return np.column_stack([first, np.full(rows.size, self._shown(np.inf))]).astype(np.float32)

    @staticmethod
    def _shown(age_s: np.ndarray | float) -> np.ndarray:
        return np.log10(1.0 + np.minimum(age_s, ONSET_CAP_S) / TIME_SCALE_S)

    def _age_shown(self, view: PeriodView) -> np.ndarray:
        """Entry 12 after advancing the change clock by the period (with this period's alarms,
        so after :meth:`_evidence`)."""
        return self._shown(self.clock.update(self.alarm, view.steps * view.dt))

    def _values(self, view: PeriodView) -> np.ndarray:
        v1 = super()._values(view)
        return np.column_stack([v1, self._age_shown(view)])


class ObservationV3(ObservationV2):
    """The 15-entry observation of ``qkf/TransferAlignment-v3``: evidence, no clock.

    ====  ======================================================================  ============
    Obs   Meaning                                                                 Typical
    ====  ======================================================================  ============
    0–3   mean ``log10(σ/σ₀)`` of the attitude, bias, scale-factor and              −3.5 … 0
          misalignment blocks of P (the covariance levels)
    4     ``log10`` of the period's mean attitude NIS / 3 (floor −2)               ≈ 0 ± 0.3
    5     ``log10`` of the period's mean rate NIS / 3 (0 without rate matching)    ≈ 0; ≤ 2 events
    6     ``log10`` of the attitude NIS / 3 over the last ``NIS_WINDOW`` periods    ≈ 0
    7     ``log10`` of the rate NIS / 3 over the last ``NIS_WINDOW`` periods        ≈ 0
    8     ``log10`` of the mean NIS per row over the last ``NIS_WINDOW`` periods   ≈ 0
    9     ``log10(1 + S)``, S the CUSUM of the period's mean NIS per row           0; ≤ 2 events
    10    ``log10(1 + t/10 s)``, t the time since the last NIS alarm (or start)    0 … 2.6
    11    ``|ω̂|`` at the end of the period, deg/s (the rate excitation)            0.06 … 1.5
    12    ``log10(1 + t/10 s)``, t the time since ω̂ last changed (a manoeuvre)     0 … 2.6
    13    position of the κ in use on the action scale                             0 … 1
    14    ``log10(1 + a/10 s)``, a the age of the current change (v2's entry 12)   0 … 3
    ====  ======================================================================  ============

    The CUSUM (9) is the one-sided GLR statistic of a rise in the NIS mean; the windowed NIS
    per block (6, 7) tells a change the attitude sees (misalignment) from one the rate
    matching sees (bias, scale factor).
    """

    size = 15
    _V2_KEPT = (3, 4, 5, 6, 7, 8, 9, 11, 12)  # v2's entries after the σ blocks, minus time

    def reset(self, rows: np.ndarray, kappa_pos: float) -> np.ndarray:
        v2 = super().reset(rows, kappa_pos)
        zeros = np.zeros((rows.size, 4))
        return self._assemble(zeros, v2, zeros[:, :2]).astype(np.float32)

    def _assemble(self, sigmas: np.ndarray, v2: np.ndarray, windows: np.ndarray) -> np.ndarray:
        kept = v2[:, self._V2_KEPT]
        # order of the table: σ levels, period NIS (2), windowed NIS per block (2), the rest
        return np.column_stack([sigmas, kept[:, :2], windows, kept[:, 2:]])

    def _values(self, view: PeriodView) -> np.ndarray:
        sm, logs = self._evidence(view)
        obs = np.empty((logs.shape[0], ObservationV3.size))
        obs[:, 0:4] = sm.levels[:, 3:7]  # sigma_ratios(view, GROUPS)
        obs[:, 4:9] = logs[:, 0:5]  # period NIS (att., rate), windowed NIS (att., rate, all)
        obs[:, 9:11] = logs[:, 5:7]  # CUSUM, time since the last alarm
        obs[:, 11] = sm.rate_norm
        obs[:, 12] = logs[:, 7]  # time since the rate changed
        obs[:, 13] = view.kappa_pos
        obs[:, 14] = self._age_shown(view)
        return obs


class ObservationV3Timed(ObservationV3):
    """``v3-time`` (``qkf/TransferAlignmentTimed-v3``, 16 entries): v3, then entry 15, the
    elapsed fraction of the episode (0 … 1): the ablation of the clock."""

    size = 16

    def reset(self, rows: np.ndarray, kappa_pos: float) -> np.ndarray:
        first = super().reset(rows, kappa_pos)
        return np.column_stack([first, np.zeros(rows.size)]).astype(np.float32)

    def _values(self, view: PeriodView) -> np.ndarray:
        return np.column_stack([super()._values(view), view.elapsed])


SLOW_WINDOWS_S = (300.0, 1000.0)
"""v4: time constants of the slow NIS means, s (exponential windows: a mean over the last τ
with weights ``e^{−age/τ}``)."""
SLOW_CUSUM_DRIFT = 0.1
"""v4: drift of the slow CUSUM ``S ← max(0, S + x − 1 − drift)``: it rises under a sustained
NIS excess of more than 10 %, which the fast CUSUM (drift 1) forgets."""


class ObservationV4(ObservationV3):
    """The 24-entry observation of ``qkf/TransferAlignment-v4``: v3's fifteen, then slow
    evidence and the moves in effect (no clock).

    ====  ======================================================================  ============
    Obs   Meaning                                                                 Typical
    ====  ======================================================================  ============
    0–14  v3 (entry 13: position of the calibration κ on the action set's range)
    15    ``log10`` of the attitude NIS / 3, exponential mean over 300 s            ≈ 0
    16    ``log10`` of the rate NIS / 3, exponential mean over 300 s                ≈ 0
    17    ``log10`` of the attitude NIS / 3, exponential mean over 1000 s           ≈ 0
    18    ``log10`` of the rate NIS / 3, exponential mean over 1000 s               ≈ 0
    19    ``log10(1 + S)``, S the slow CUSUM (drift 0.1) of the NIS per row        0; rises slowly
    20    ``log10 q_att``, the attitude process-noise factor in use                −1 … 1
    21    ``log10 q_bias``, the bias process-noise factor in use                   −1 … 1
    22    ``log2 r_scale``, the factor on the assumed ADS σ in use                 −1 … 2
    23    ``log10(1 + t/10 s)``, t the time since the last reset (cap 10⁴ s)       0 … 3
    ====  ======================================================================  ============

    A slow calibration drift raises the NIS by a few per cent for hundreds of seconds: the
    300–1000 s means and the slow CUSUM (15–19) see it where v3's 60-s window cannot. A
    mis-stated ADS noise shows as an attitude NIS mean away from 1 over 1000 s (17).
    """

    size = 24

    def __init__(self, cfg: Config, n: int, period_s: float) -> None:
        super().__init__(cfg, n, period_s)
        self.slow = np.ones((n, 4))  # EMAs of x_att, x_rate over 300 s, then over 1000 s
        self.slow_cusum = np.zeros(n)
        self.since_reset = np.full(n, ONSET_CAP_S)

    def reset(self, rows: np.ndarray, kappa_pos: float) -> np.ndarray:
        v3 = super().reset(rows, kappa_pos)
        self.slow[rows] = 1.0
        self.slow_cusum[rows] = 0.0
        self.since_reset[rows] = ONSET_CAP_S
        extra = np.zeros((rows.size, 9))
        extra[:, 8] = self._shown(ONSET_CAP_S)
        return np.column_stack([v3, extra]).astype(np.float32)

    def _values(self, view: PeriodView) -> np.ndarray:
        v3 = super()._values(view)
        sm = view.summary
        period_s = view.steps * view.dt
        # the period's mean NIS per row of attitude and rate (1 where the period had none)
        x = np.where(sm.nis_count[:, :2] > 0, sm.nis_mean[:, :2] / 3.0, 1.0)
        x = np.where(np.isfinite(x), x, OBS_LIMIT)
        taus = np.repeat(np.asarray(SLOW_WINDOWS_S), 2)
        alpha = 1.0 - np.exp(-period_s[:, None] / taus[None, :])  # weight of this period
        self.slow += alpha * (np.tile(x, 2) - self.slow)  # m ← m + α (x − m)
        rows = np.where(sm.nis_count[:, 2] > 0, sm.nis_mean[:, 2] / view.n_meas, 1.0)
        rows = np.where(np.isfinite(rows), rows, OBS_LIMIT)
        self.slow_cusum = np.maximum(0.0, self.slow_cusum + rows - 1.0 - SLOW_CUSUM_DRIFT)
        moves = view.moves if view.moves is not None else Moves.nominal(v3.shape[0])
        reset = moves.reset > 0.0  # a reset at this period's start
        self.since_reset = np.where(reset, period_s, self.since_reset + period_s)
        extra = np.column_stack(
            [
                np.log10(np.maximum(self.slow, LOG_FLOOR)),
                np.log10(1.0 + self.slow_cusum),
                np.log10(moves.q_att),
                np.log10(moves.q_bias),
                np.log2(moves.r_scale),
                self._shown(self.since_reset),
            ]
        )
        return np.column_stack([v3, extra])


OBSERVATIONS.register(
    "v0",
    Observation(
        ObservationV0,
        ObservationV0.size,
        "v0: P blocks, mean NIS, likelihood gain (≈ 1e-6 … 5e-4), time, |ω̂|, κ",
        needs_likelihood=True,
    ),
)
OBSERVATIONS.register(
    "v1",
    Observation(
        ObservationV1,
        ObservationV1.size,
        "v1: P blocks, log NIS, windowed NIS, CUSUM, time since alarm, |ω̂|, time since "
        "the rate changed, time, κ (all of order one)",
    ),
)
OBSERVATIONS.register(
    "v2",
    Observation(
        ObservationV2,
        ObservationV2.size,
        "v2: v1 and the age of the current change (time since the first alarm of the present "
        "run of alarms)",
    ),
)
OBSERVATIONS.register(
    "v3",
    Observation(
        ObservationV3,
        ObservationV3.size,
        "v3: P levels of the four blocks, period and windowed NIS per block, CUSUM, time since "
        "alarm, |ω̂|, time since the rate changed, κ, age of the change (no clock)",
    ),
)
OBSERVATIONS.register(
    "v4",
    Observation(
        ObservationV4,
        ObservationV4.size,
        "v4: v3, slow NIS means (300 s, 1000 s) per block, a slow CUSUM, the moves in use and "
        "the time since the last reset (no clock)",
    ),
)
OBSERVATIONS.register(
    "v3-time",
    Observation(
        ObservationV3Timed,
        ObservationV3Timed.size,
        "v3 and the elapsed fraction of the episode (the ablation of the clock)",
    ),
)
