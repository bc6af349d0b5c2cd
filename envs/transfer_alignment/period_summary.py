r"""What every observation reads of a decision period, in one compiled pass (docs/performance.md).

The observations (:mod:`envs.transfer_alignment.observations`) reduce the filter's record of a
period to a few numbers per episode: masked means of the NIS columns, the covariance levels of
blocks of states at the period's last valid epoch, and the rate there. Written as numpy
reductions these are some forty calls on arrays of ten epochs, and for one episode (the single
environment) their call overhead was the largest part of a step. :func:`period_summary` does
them in one compiled call; the numpy definitions (:func:`~envs.transfer_alignment.observations.
masked_mean`, :func:`~envs.transfer_alignment.observations.sigma_ratios`) stay the reference
the tests hold it to.

Per episode ``i`` of N, over the period's P epochs, with ``ok_k = valid_k ∧ isfinite(x_k)``::

    mean_c   = Σ_k ok_k x_k,c / max(n_c, 1),  n_c = Σ_k ok_k       c = NIS att., rate, all
    level_j  = mean_{s ∈ block j} ½ log10(P_ss / σ0_s²)            at the last valid epoch
    rate     = ω̂ / (π/180)                                        deg/s, at the last valid epoch

Sums run in epoch order; numpy's pairwise sums round differently in the last bit, which the
float32 observations do not see (the tests allow one float32 unit in the last place).
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

import qkf.core.jit  # noqa: F401  (binds compiled callees locally: docs/performance.md)
from qkf.core.jit import kernel_array
from qkf.transfer_alignment.filter import FilterRecord

DEG = np.pi / 180.0


class Summary(NamedTuple):
    """Output of :func:`period_summary` for N episodes."""

    nis_mean: np.ndarray  # (N, 3) masked means of NIS att., NIS rate, NIS (0 where none)
    nis_count: np.ndarray  # (N, 3) finite valid epochs behind each mean
    levels: np.ndarray  # (N, K) mean ½ log10(P_ss/σ0_s²) of each block at the last epoch
    rate_deg_s: np.ndarray  # (N, 3) ω̂ at the last epoch, deg/s
    rate_norm: np.ndarray  # (N,) |ω̂| there, deg/s


@nb.njit(cache=True)
def _masked_mean(x: np.ndarray, valid: np.ndarray) -> tuple[float, int]:
    """``Σ ok x / max(n, 1)`` and ``n`` over the finite, valid entries of one row."""
    total = 0.0
    count = 0
    for k in range(x.shape[0]):
        if valid[k] and np.isfinite(x[k]):
            total += x[k]
            count += 1
    return total / max(count, 1), count


@nb.njit(cache=True)
def _summarise(
    nis_att: np.ndarray,
    nis_rate: np.ndarray,
    nis: np.ndarray,
    var: np.ndarray,
    rate: np.ndarray,
    valid: np.ndarray,
    last: np.ndarray,
    p0_var: np.ndarray,
    blocks: np.ndarray,
    nis_mean: np.ndarray,
    nis_count: np.ndarray,
    levels: np.ndarray,
    rate_deg: np.ndarray,
    rate_norm: np.ndarray,
) -> None:
    for i in range(valid.shape[0]):
        nis_mean[i, 0], nis_count[i, 0] = _masked_mean(nis_att[i], valid[i])
        nis_mean[i, 1], nis_count[i, 1] = _masked_mean(nis_rate[i], valid[i])
        nis_mean[i, 2], nis_count[i, 2] = _masked_mean(nis[i], valid[i])
        k = last[i]
        for j in range(blocks.shape[0]):
            lo, hi = blocks[j, 0], blocks[j, 1]
            total = 0.0
            for s in range(lo, hi):
                total += 0.5 * np.log10(var[i, k, s] / p0_var[s])  # ½ log10(P_ss / σ0_s²)
            levels[i, j] = total / (hi - lo)
        sq = 0.0
        for a in range(3):
            r = rate[i, k, a] / DEG  # rad/s → deg/s
            rate_deg[i, a] = r
            sq += r * r
        rate_norm[i] = np.sqrt(sq)


def period_summary(
    record: FilterRecord,
    valid: np.ndarray,
    last: np.ndarray,
    p0_sigma: np.ndarray,
    blocks: np.ndarray,
) -> Summary:
    """The module's reductions for N episodes of a period of P epochs.

    ``record``: the filter over the period (its NIS columns, (N, P), NaN where none; ``var``
    (N, P, 15) diag P in SI; ``rate`` (N, P, 3) ω̂ in rad/s); ``valid`` (N, P) bool; ``last``
    (N,) the last valid epoch; ``p0_sigma`` (15,) prior sigmas (SI); ``blocks`` (K, 2) int,
    ``[start, stop)`` of each block of states.
    """
    n = valid.shape[0]
    out = Summary(
        nis_mean=np.empty((n, 3)),
        nis_count=np.empty((n, 3), dtype=np.int64),
        levels=np.empty((n, blocks.shape[0])),
        rate_deg_s=np.empty((n, 3)),
        rate_norm=np.empty(n),
    )
    # one array type whatever the record's views (a column of its stats, a gathered copy) or a
    # read-only mask: each other type compiles the routine again (qkf.core.jit.kernel_array)
    nis_att, nis_rate, nis, var, rate = (kernel_array(a, float, a.shape) for a in (
        record.nis_att, record.nis_rate, record.nis, record.var, record.rate,
    ))  # fmt: skip
    _summarise(
        nis_att,
        nis_rate,
        nis,
        var,
        rate,
        kernel_array(valid, np.bool_, valid.shape),
        kernel_array(last, np.int64, np.shape(last)),
        np.asarray(p0_sigma, dtype=float) ** 2,
        blocks,
        *out,
    )
    return out


def block_table(blocks: tuple[slice, ...]) -> np.ndarray:
    """``[start, stop)`` of each slice of states, a (K, 2) int array (:func:`period_summary`)."""
    return np.array([[sl.start, sl.stop] for sl in blocks], dtype=np.int64)


class EvidenceConstants(NamedTuple):
    """The settings of :func:`update_evidence` (names as in the observations module)."""

    cusum_drift: float  # CUSUM_DRIFT
    nis_alarm: float  # alarm threshold on the period's mean NIS per row
    rate_change_deg_s: float  # RATE_CHANGE_DEG_S
    time_scale_s: float  # TIME_SCALE_S
    log_floor: float  # LOG_FLOOR
    obs_limit: float  # OBS_LIMIT: a non-finite NIS mean per row is taken as this


@nb.njit(cache=True)
def _floored_log10(x: float, floor: float) -> float:
    """``log10(max(x, floor))`` with numpy's NaN semantics (NaN stays NaN)."""
    return np.log10(floor if x < floor else x)


@nb.njit(cache=True)
def _update_evidence(
    nis_mean: np.ndarray,
    nis_count: np.ndarray,
    n_meas: int,
    period_s: np.ndarray,
    rate_deg: np.ndarray,
    c: EvidenceConstants,
    cusum: np.ndarray,
    windows: np.ndarray,
    since_alarm: np.ndarray,
    since_rate_change: np.ndarray,
    last_rate: np.ndarray,
    alarm: np.ndarray,
    logs: np.ndarray,
) -> None:
    empty = (3.0, 3.0, float(n_meas))  # what a period without a measurement shows
    w = windows.shape[2]
    for i in range(nis_mean.shape[0]):
        x = np.empty(3)
        for b in range(3):
            # the period's mean NIS per row: attitude, rate, all rows
            x[b] = (nis_mean[i, b] if nis_count[i, b] > 0 else empty[b]) / empty[b]
        if not np.isfinite(x[2]):
            x[2] = c.obs_limit
        cusum[i] = max(0.0, cusum[i] + x[2] - 1.0 - c.cusum_drift)  # S ← max(0, S + x − 1 − k)
        for b in range(3):
            total = 0.0
            for j in range(w - 1):  # drop the oldest period, append this one
                windows[i, b, j] = windows[i, b, j + 1]
                total += windows[i, b, j]
            windows[i, b, w - 1] = x[b]
            logs[i, 2 + b] = _floored_log10((total + x[b]) / w, c.log_floor)
        alarm[i] = x[2] > c.nis_alarm
        since_alarm[i] = 0.0 if alarm[i] else since_alarm[i] + period_s[i]
        d2 = 0.0
        for a in range(3):
            d2 += (rate_deg[i, a] - last_rate[i, a]) ** 2
            last_rate[i, a] = rate_deg[i, a]
        changed = np.sqrt(d2) > c.rate_change_deg_s  # False while no period was seen (NaN)
        since_rate_change[i] = 0.0 if changed else since_rate_change[i] + period_s[i]
        logs[i, 0] = _floored_log10(x[0], c.log_floor)
        logs[i, 1] = _floored_log10(x[1], c.log_floor)
        logs[i, 5] = np.log10(1.0 + cusum[i])
        logs[i, 6] = np.log10(1.0 + since_alarm[i] / c.time_scale_s)
        logs[i, 7] = np.log10(1.0 + since_rate_change[i] / c.time_scale_s)


EVIDENCE_COLUMNS = (
    "log NIS att.",
    "log NIS rate",
    "log windowed NIS att.",
    "log windowed NIS rate",
    "log windowed NIS",
    "log (1 + CUSUM)",
    "log (1 + time since alarm / scale)",
    "log (1 + time since the rate changed / scale)",
)
"""The columns of :func:`update_evidence`'s output."""


def update_evidence(
    summary: Summary,
    n_meas: int,
    period_s: np.ndarray,
    constants: EvidenceConstants,
    cusum: np.ndarray,
    windows: np.ndarray,
    since_alarm: np.ndarray,
    since_rate_change: np.ndarray,
    last_rate: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Advance the change-detection state of observations v1–v3 by one period, in place, and
    return ``(alarm, logs)``: this period's alarms (N,) bool and the :data:`EVIDENCE_COLUMNS`
    (N, 8).

    Per episode, with ``x_b`` the period's mean NIS per row of block b (attitude, rate, all;
    ``3, 3, n_meas`` where the period had no measurement, then divided by the same)::

        S ← max(0, S + x_all − 1 − drift)                  CUSUM (``cusum``, (N,))
        window_b ← last W periods' x_b                      (``windows``, (N, 3, W))
        alarm = x_all > nis_alarm;  t_alarm ← 0 if alarm else t_alarm + period
        t_rate ← 0 if |ω̂ − ω̂_prev| > rate_change else t_rate + period   (deg/s)

    ``since_alarm``, ``since_rate_change`` (N,) s and ``last_rate`` (N, 3) deg/s are updated
    too. ``period_s`` (N,): seconds filtered in this period.
    """
    n = period_s.shape[0]
    alarm = np.empty(n, dtype=np.bool_)
    logs = np.empty((n, len(EVIDENCE_COLUMNS)))
    _update_evidence(
        summary.nis_mean,
        summary.nis_count,
        n_meas,
        np.ascontiguousarray(period_s, dtype=float),
        summary.rate_deg_s,
        constants,
        cusum,
        windows,
        since_alarm,
        since_rate_change,
        last_rate,
        alarm,
        logs,
    )
    return alarm, logs
