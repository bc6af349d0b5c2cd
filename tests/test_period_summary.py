"""The compiled period summary of the observations against their numpy definitions
(``masked_mean``, ``sigma_ratios``, ``rate_deg_s``), on random records with invalid epochs,
non-finite NIS values and rows without any valid epoch."""

from __future__ import annotations

import numpy as np

from envs.transfer_alignment.observations import (
    LEVEL_BLOCKS,
    PeriodView,
    masked_mean,
    rate_deg_s,
    sigma_ratios,
)
from envs.transfer_alignment.period_summary import block_table, period_summary
from qkf.transfer_alignment.filter import FilterRecord
from qkf.transfer_alignment.states import GROUPS


def _view(seed: int, n: int = 7, p: int = 10) -> PeriodView:
    rng = np.random.default_rng(seed)
    stats = rng.chisquare(3, size=(n, p, 5))
    stats[rng.random((n, p, 5)) < 0.15] = np.nan  # epochs without a measurement
    stats[0, 3, 0] = np.inf
    stats[1, :, 1] = np.nan  # no rate NIS at all in episode 1
    valid = rng.random((n, p)) < 0.8
    valid[2] = False  # an episode already over
    valid[3] = True
    p0 = rng.uniform(1e-6, 1e-2, 15)
    var = (p0 * 10.0 ** rng.uniform(-4, 0, size=(n, p, 15))) ** 2
    rate = rng.normal(scale=0.02, size=(n, p, 3))
    last = np.maximum(valid.sum(axis=1) - 1, 0)
    rec = FilterRecord(
        est=np.zeros((n, p, 16)),
        var=var,
        cov=None,
        dx=np.zeros((n, p, 15)),
        innov=np.zeros((n, p, 6)),
        nis_att=stats[..., 0],
        nis_rate=stats[..., 1],
        nis=stats[..., 2],
        logdet_s=stats[..., 3],
        trace_s_att=stats[..., 4],
        rate=rate,
    )
    return PeriodView(
        record=rec,
        valid=valid,
        last=last,
        steps=np.maximum(valid.sum(axis=1), 1),
        loglik_gain=None,
        elapsed=np.full(n, 0.5),
        kappa_pos=np.full(n, 0.5),
        p0_sigma=p0,
        n_meas=6,
        dt=1.0,
    )


def test_summary_equals_the_numpy_definitions() -> None:
    for seed in range(5):
        view = _view(seed)
        rec = view.record
        for c, col in enumerate((rec.nis_att, rec.nis_rate, rec.nis)):
            for empty in (0.0, 3.0):
                means = view.nis_means(empty, empty, empty)[:, c]
                np.testing.assert_allclose(
                    means, masked_mean(col, view.valid, empty), rtol=1e-14, atol=0.0
                )
        levels = view.summary.levels
        np.testing.assert_allclose(levels[:, 0:3], sigma_ratios(view), rtol=1e-13)
        np.testing.assert_allclose(
            levels[:, 3:7], sigma_ratios(view, tuple(GROUPS.values())), rtol=1e-13
        )
        np.testing.assert_allclose(view.summary.rate_deg_s, rate_deg_s(view), rtol=1e-15)
        np.testing.assert_allclose(
            view.summary.rate_norm, np.linalg.norm(rate_deg_s(view), axis=1), rtol=1e-15
        )


def test_rows_without_valid_epochs_and_counts() -> None:
    view = _view(1)
    sm = view.summary
    assert (sm.nis_count[2] == 0).all()  # the episode that is over
    assert sm.nis_count[1, 1] == 0  # no rate NIS
    ok = view.valid[0] & np.isfinite(view.record.nis_att[0])
    assert sm.nis_count[0, 0] == ok.sum()  # the inf is left out like a NaN
    np.testing.assert_array_equal(view.nis_means(3.0, 7.0, 6.0)[2], [3.0, 7.0, 6.0])


def test_blocks_are_independent_of_their_order() -> None:
    """Each block's level depends on its states only: reversing the table reverses the output."""
    view = _view(3)
    table = block_table(LEVEL_BLOCKS)
    args = (view.record, view.valid, view.last, view.p0_sigma)
    fwd = period_summary(*args, table).levels
    rev = period_summary(*args, table[::-1].copy()).levels
    np.testing.assert_array_equal(fwd, rev[:, ::-1])


def test_evidence_update_equals_a_numpy_transcription() -> None:
    """``update_evidence`` over 40 periods of 6 episodes against the equations of its docstring
    written out in numpy: the alarms exactly, the logs and the state to rounding."""
    from envs.common.bounds import OBS_LIMIT
    from envs.transfer_alignment.observations import (
        CUSUM_DRIFT,
        LOG_FLOOR,
        NIS_WINDOW,
        RATE_CHANGE_DEG_S,
        TIME_SCALE_S,
    )
    from envs.transfer_alignment.period_summary import EvidenceConstants, Summary, update_evidence

    rng = np.random.default_rng(8)
    n, n_meas, nis_alarm = 6, 6, 4.0
    c = EvidenceConstants(
        CUSUM_DRIFT, nis_alarm, RATE_CHANGE_DEG_S, TIME_SCALE_S, LOG_FLOOR, OBS_LIMIT
    )
    state = (
        np.zeros(n),
        np.ones((n, 3, NIS_WINDOW)),
        np.zeros(n),
        np.zeros(n),
        np.full((n, 3), np.nan),
    )
    ref = [a.copy() for a in state]
    rate = rng.normal(scale=0.3, size=(n, 3))
    seen = np.zeros(2, dtype=int)  # periods with and without an alarm
    for _ in range(40):
        means = rng.chisquare(3, size=(n, 3)) * rng.choice([0.3, 1.0, 5.0], size=(n, 1))
        counts = rng.integers(0, 3, size=(n, 3))  # 0: no measurement in the period
        means[0, 2] = np.inf  # a non-finite mean per row is shown as OBS_LIMIT
        rate = np.where(rng.random((n, 1)) < 0.3, rng.normal(scale=0.3, size=(n, 3)), rate)
        period = rng.choice([10.0, 4.0], size=n)
        sm = Summary(means, counts, np.zeros((n, 0)), rate.copy(), np.linalg.norm(rate, axis=1))
        alarm, logs = update_evidence(sm, n_meas, period, c, *state)
        # the reference, straight from the equations
        cusum, windows, t_alarm, t_rate, last = ref
        empty = np.array([3.0, 3.0, n_meas])
        x = np.where(counts > 0, means, empty) / empty
        x[:, 2] = np.where(np.isfinite(x[:, 2]), x[:, 2], OBS_LIMIT)
        cusum[:] = np.maximum(0.0, cusum + x[:, 2] - 1.0 - CUSUM_DRIFT)
        windows[:] = np.concatenate([windows[:, :, 1:], x[:, :, None]], axis=2)
        ref_alarm = x[:, 2] > nis_alarm
        t_alarm[:] = np.where(ref_alarm, 0.0, t_alarm + period)
        moved = np.linalg.norm(rate - last, axis=1) > RATE_CHANGE_DEG_S
        t_rate[:] = np.where(moved, 0.0, t_rate + period)
        last[:] = rate
        expect = np.column_stack(
            [
                np.log10(np.maximum(x[:, 0:2], LOG_FLOOR)),
                np.log10(np.maximum(windows.mean(axis=2), LOG_FLOOR)),
                np.log10(1.0 + cusum),
                np.log10(1.0 + t_alarm / TIME_SCALE_S),
                np.log10(1.0 + t_rate / TIME_SCALE_S),
            ]
        )
        np.testing.assert_array_equal(alarm, ref_alarm)
        seen += [ref_alarm.sum(), (~ref_alarm).sum()]
        np.testing.assert_allclose(logs, expect, rtol=1e-13, atol=1e-15)
        for got, want in zip(state, ref, strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-15)
    assert seen.min() > 20  # alarms and quiet periods both exercised
