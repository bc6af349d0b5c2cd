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
    rec = view.record
    table = block_table(LEVEL_BLOCKS)
    args = (rec.nis_att, rec.nis_rate, rec.nis, rec.var, rec.rate, view.valid, view.last)
    fwd = period_summary(*args, view.p0_sigma, table).levels
    rev = period_summary(*args, view.p0_sigma, table[::-1].copy()).levels
    np.testing.assert_array_equal(fwd, rev[:, ::-1])
