"""The pieces of the compiled κ bank (qkf/transfer_alignment/methods/bank_compiled.py) batched
over trials, with the arguments of their numpy references, for tests/test_bank_compiled.py.

Each piece runs per trial (a per-row routine here), and :func:`qkf.core.jit.row_loops` runs
the rows one after the other: its serial loop compiles in a fraction of the parallel one's
time (a parallel loop is a second, larger compilation; 1–3 s a piece here), and the tests'
batches are a few rows. Compiled without numba's on-disk cache: numba would check a cache entry
against this file only, and the copies of the bank's routines compiled into it would go stale
when bank_compiled.py changes (qkf.core.numba_cache covers the package, not the tests).
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit, row_loops
from qkf.transfer_alignment import kernel as _ta_kernel
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.methods.bank_compiled import (
    _make_work,
    combine_one,
    mix_trial,
    mixture_covariance_one,
    split_transitions,
    unit_noise,
    unit_noise_coefficients,
)

_test_jit = kernel_jit(nrt=True, cache=False)


@_test_jit
def _unit_noise_row(
    t: int,
    dt: float,
    coef_g: np.ndarray,
    coef_tt: np.ndarray,
    rate: np.ndarray,
    p_hat: np.ndarray,
    u: np.ndarray,
) -> None:
    unit_noise(dt, coef_g, coef_tt, rate[t], p_hat[t], u[t], _make_work(1))


_unit_noise_rows = row_loops(_unit_noise_row, "rate.shape[0]", cache=False).serial


def unit_calibration_noise_compiled(dt: float, rate: np.ndarray, p_hat: np.ndarray) -> np.ndarray:
    """:func:`unit_noise` for rows of ``rate`` (B, 3) rad/s and ``p_hat`` (B, 9): (B, 15, 15) s."""
    rate = np.ascontiguousarray(rate, dtype=float)
    u = np.empty((rate.shape[0], 15, 15))
    coef_g, coef_tt = unit_noise_coefficients(float(dt))
    _unit_noise_rows(float(dt), coef_g, coef_tt, rate, np.ascontiguousarray(p_hat, dtype=float), u)
    return u


@_test_jit
def _mix_row(
    t: int,
    state: _ta_kernel.FilterState,
    mu: np.ndarray,
    trans: np.ndarray,
    trans_c: float,
    trans_r: np.ndarray,
    kq: np.ndarray,
    unit_q: np.ndarray,
    inv_d: np.ndarray,
    inv_dd: np.ndarray,
    live: np.ndarray,
    c_bar: np.ndarray,
) -> None:
    n_act = kq.shape[0]
    wk = _make_work(n_act)
    mix_trial(
        state, t * n_act, mu[t], trans, trans_c, trans_r, kq, unit_q[t], inv_d, inv_dd,
        live[t], c_bar[t], wk,
    )  # fmt: skip


_mix_rows = row_loops(_mix_row, "mu.shape[0]", cache=False).serial


def mix_bank_compiled(
    kf: TransferAlignmentKF,
    mu: np.ndarray,
    trans: np.ndarray,
    kappas: np.ndarray,
    unit_q: np.ndarray,
    live: np.ndarray,
) -> np.ndarray:
    """:func:`mix_trial` for every trial of the bank ``kf``: the compiled ``imm.mix_bank``, with
    its arguments; returns ``c̄`` (B, A)."""
    c_bar = np.empty(mu.shape)
    trans = np.ascontiguousarray(trans, dtype=float)
    trans_c, trans_r = split_transitions(trans)
    _mix_rows(
        _ta_kernel.FilterState(*kf._kernel_state()),
        np.ascontiguousarray(mu, dtype=float),
        trans,
        trans_c,
        trans_r,
        np.asarray(kappas, dtype=float) * float(kf.params.qp0),
        np.ascontiguousarray(unit_q, dtype=float),
        1.0 / kf._d,
        1.0 / np.outer(kf._d, kf._d),
        np.ascontiguousarray(live, dtype=bool),
        c_bar,
    )
    return c_bar


@_test_jit
def _combine_row(t: int, est: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    rel = np.empty((w.shape[2], 3))
    for k in range(w.shape[1]):
        combine_one(est[t, k], w[t, k], out[t, k], rel)


_combine_rows = row_loops(_combine_row, "w.shape[0]", cache=False).serial


def combine_compiled(est: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`combine_one` at every trial and epoch: ``est`` (B, A, n, 16) finite, ``w``
    (B, A, n) → (B, n, 16), as ``mmae.combine``."""
    out = np.empty((w.shape[0], w.shape[2], 16))
    _combine_rows(
        np.ascontiguousarray(np.moveaxis(est, 1, 2), dtype=float),
        np.ascontiguousarray(np.moveaxis(w, 1, 2), dtype=float),
        out,
    )
    return out


@_test_jit
def _mixture_row(
    t: int, est: np.ndarray, cov: np.ndarray, w: np.ndarray, est_mix: np.ndarray, out: np.ndarray
) -> None:
    n_act = w.shape[1]
    scratch = np.empty((n_act, 15))
    used = np.empty(n_act, dtype=np.bool_)
    mixture_covariance_one(est[t], cov[t], w[t], est_mix[t], out[t], scratch, used)


_mixture_rows = row_loops(_mixture_row, "w.shape[0]", cache=False).serial


def mixture_covariance_compiled(
    est: np.ndarray, cov: np.ndarray, weights: np.ndarray, est_mix: np.ndarray
) -> np.ndarray:
    """:func:`mixture_covariance_one` for every trial, with the arguments of
    ``covariance.mixture_covariance`` (``est`` (B, A, 16), ``cov`` (B, A, 15, 15),
    ``weights`` (B, A), ``est_mix`` (B, 16)) → (B, 15, 15)."""
    out = np.empty((weights.shape[0], 15, 15))
    _mixture_rows(
        np.ascontiguousarray(est, dtype=float),
        np.ascontiguousarray(cov, dtype=float),
        np.ascontiguousarray(weights, dtype=float),
        np.ascontiguousarray(est_mix, dtype=float),
        out,
    )
    return out
