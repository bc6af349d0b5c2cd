r"""QKF: the online Q-learning Kalman filter with one explorative filter (docs/methods.md).

State ``s`` = index of the κ the main filter uses; Q-table (A × A) per trial, zero at start.
Every decision period ``T_c``:

1. pick an action ``a`` ε-greedily from ``Q(s, ·)`` (ties broken at random);
2. copy the main filter into the explorative filter;
3. run both over the period, main with ``κ_s``, explorative with ``κ_a``;
4. reward ``r = (ℓ_explore − ℓ_main) / T_c`` with the innovation log-likelihood
   ``ℓ = −½ Σ (νᵀ S⁻¹ ν + log det S)`` over the period (flight-realisable: no truth);
5. ``Q(s, a) += α (r + γ max_a' Q(a, a') − Q(s, a))``;
6. the main filter switches to ``argmax_a Q(s, a)`` if that value is positive, else stays.

Options (departures from the paper's rule, off by default; docs/methods.md): a switch threshold
(``switch_threshold``: switch only if ``max_a Q(s, a)`` exceeds it), hysteresis (``hysteresis``:
and only if it exceeds ``Q(s, s)`` by more than that), and reward normalisation
(``reward_normalization: running_rms``: each reward divided by the running RMS of the trial's
rewards so far, so that α and the thresholds act on a unit scale whatever the scenario).

ε decays as ``ε_end + (ε_start − ε_end) exp(−t / τ)``. Each trial draws its ε-greedy choices
from its own generator (seeded by the run's seed and the trial index), so trial ``i`` is
reproducible on its own.
"""

from __future__ import annotations

import math

import numpy as np

from qkf.transfer_alignment.adaptive import QkfConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    EpochRecords,
    MethodOutput,
    action_values,
    decision_steps,
    method_rng,
    new_filter,
    per_epoch,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder, step_recording
from qkf.transfer_alignment.scenario import ScenarioData

DIVERGENCE_PENALTY = -1e9
"""Reward for a period in which the explorative filter diverged, per second."""


def q_update(
    table: np.ndarray, s: np.ndarray, a: np.ndarray, r: np.ndarray, alpha: float, gamma: float
) -> None:
    """In-place Q-learning update of per-trial tables (B, A, A); s, a, r are (B,)."""
    rows = np.arange(table.shape[0])
    target = r + gamma * table[rows, a].max(axis=1)
    table[rows, s, a] += alpha * (target - table[rows, s, a])


def greedy_switch(
    table: np.ndarray, s: np.ndarray, threshold: float = 0.0, hysteresis: float = 0.0
) -> np.ndarray:
    """Next state: ``a* = argmax_a Q(s, a)`` where ``Q(s, a*) > threshold`` (the paper's rule:
    threshold 0) and, with ``hysteresis > 0``, ``Q(s, a*) − Q(s, s) > hysteresis``; else ``s``."""
    rows = np.arange(table.shape[0])
    q_row = table[rows, s]
    best = q_row.argmax(axis=1)
    q_best = q_row[rows, best]
    switch = q_best > threshold
    if hysteresis > 0.0:
        switch &= q_best - q_row[rows, s] > hysteresis
    return np.where(switch, best, s)


def normalize_reward(r: np.ndarray, sum_sq: np.ndarray, count: int) -> np.ndarray:
    """``r / RMS(r_1 … r_j)``: the reward in units of its own running RMS (per trial, the
    current reward included; 0 stays 0). ``sum_sq`` (B,) is updated in place."""
    sum_sq += r * r
    rms = np.sqrt(sum_sq / count)
    return np.where(rms > 0.0, r / np.where(rms > 0.0, rms, 1.0), 0.0)


def epsilon_at(cfg: Config, t_s: float) -> float:
    q = cfg.adaptive.qkf
    return q.epsilon_end + (q.epsilon_start - q.epsilon_end) * math.exp(-t_s / q.epsilon_decay_s)


@uses_settings("qkf", QkfConfig)
def run_qkf(cfg: Config, data: ScenarioData) -> MethodOutput:
    """QKF over all trials; logs the main filter's κ index per period (``kappa_index``)."""
    qc = cfg.adaptive.qkf
    kappas = action_values(cfg)
    n_act = kappas.size
    b, n = data.n_trials, data.n_epochs
    period = decision_steps(qc.period_s, cfg.scenario.dt_s)
    main = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    explore = new_filter(cfg, data)
    rngs = [method_rng(data, i, stream=1) for i in range(b)]
    table = np.zeros((b, n_act, n_act))
    s = np.full(b, cfg.adaptive.actions.nominal_index())  # start at κ = 1
    est = np.empty((b, n, 16))
    starts = list(range(0, n, period))
    kappa_index = np.empty((b, len(starts)), dtype=np.int64)
    rewards = np.empty((b, len(starts)))
    actions = np.empty((b, len(starts)), dtype=np.int64)
    reward_sq = np.zeros(b)
    epochs = EpochRecords(b, n)
    for j, k0 in enumerate(starts):
        k1 = min(n, k0 + period)
        eps = epsilon_at(cfg, k0 * cfg.scenario.dt_s)
        a = np.empty(b, dtype=np.int64)
        for i, g in enumerate(rngs):
            q_row = table[i, s[i]]
            if g.random() < eps:
                a[i] = g.integers(n_act)
            else:
                a[i] = g.choice(np.flatnonzero(q_row == q_row.max()))
        explore.copy_state_from(main)
        kappa_index[:, j] = s
        actions[:, j] = a
        rec_m = step_recording(main, data, k0, k1, kappas[s], cov)
        rec_e = explore.step_data(data, k0, k1, kappa=kappas[a])
        est[:, k0:k1] = rec_m.est
        epochs.put(k0, rec_m)
        t_c = (k1 - k0) * cfg.scenario.dt_s
        r = (rec_e.loglik.sum(axis=1) - rec_m.loglik.sum(axis=1)) / t_c
        # a diverging explorative filter earns a prohibitive penalty (its ℓ is −inf)
        r = np.where(np.isfinite(r), r, DIVERGENCE_PENALTY)
        if qc.reward_normalization == "running_rms":
            r = normalize_reward(r, reward_sq, j + 1)
        rewards[:, j] = r
        q_update(table, s, a, r, qc.alpha, qc.gamma)
        s = greedy_switch(table, s, qc.switch_threshold, qc.hysteresis)
    out = MethodOutput(
        est=est,
        diverged=main.diverged.copy(),
        kappa=per_epoch(kappas[kappa_index], period, n),
        logs={
            "kappa_index": kappa_index,
            "period_start_s": np.asarray(starts) * cfg.scenario.dt_s,
            "reward": rewards,
            "action": actions,
            "q_table": table,
        },
        cov=cov.cov,
    )
    return epochs.attach(out)
