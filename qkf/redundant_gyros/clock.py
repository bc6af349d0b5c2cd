r"""The gyro ``clock``: a κ schedule of time alone, tuned (docs/redundant_gyros.md, "Clock").

κ_a from the start of the calibration up to the switch time ``t_s`` (rounded to a decision
period), κ_c from it on, the same for every episode: what a filter designer who knows the
family (when its changes tend to come, how the convergence goes) but nothing of the episode
would schedule. The grid: every pair of the action set's κ (11 × 11) and the switch times
:data:`SWITCH_S` (whole run: no switch), 121 × 6 = 726 points, at least the 50 evaluations of
the tuned baselines; :func:`tune` keeps the point with the lowest mean ``J`` (the hindsight's
criterion) over the tuning episodes. With ``t_s`` at the end it is the best constant κ, so the
tuned clock is never worse than the best constant on its tuning episodes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros.config import GyrosConfig

SWITCH_S = (50.0, 100.0, 200.0, 300.0, 400.0, float("inf"))
"""Switch times of the grid, s after the calibration starts (inf: never)."""


@dataclass(frozen=True)
class Clock:
    """κ ``before`` up to ``switch_s`` (s after the calibration starts), ``after`` from it on."""

    before: float
    after: float
    switch_s: float

    def switch_epoch(self, ep: hs.Episode) -> int:
        """The first epoch of κ ``after`` in episode ``ep``: the start of the first period at
        or after ``switch_s`` (``n_epochs``: never)."""
        since = np.cumsum(ep.inputs.dt) - ep.inputs.dt[0]
        k_sw = min(ep.n_epochs, int(np.searchsorted(since, self.switch_s - 1e-9)))
        return min(ep.n_epochs, -(-k_sw // ep.period) * ep.period)

    def kappa(self, ep: hs.Episode) -> np.ndarray:
        """κ per epoch (n_epochs,) of episode ``ep``."""
        out = np.full(ep.n_epochs, self.after)
        out[: self.switch_epoch(ep)] = self.before
        return out


def score(ep: hs.Episode, clock: Clock) -> float:
    """``J`` of episode ``ep`` under ``clock``."""
    ukf = hs.CompiledUKF(ep)
    x, p = ukf.prior()
    return ukf.score(ukf.run(x, p, clock.kappa(ep), 0, ep.n_epochs))


def grid_scores(ep: hs.Episode) -> np.ndarray:
    """``J`` (len(SWITCH_S), A, A) of every clock of the grid on episode ``ep``: the filter
    runs once per κ_a up to each switch, then once per κ_c from there."""
    ukf = hs.CompiledUKF(ep)
    a_n, n = ep.kappas.size, ep.n_epochs
    out = np.empty((len(SWITCH_S), a_n, a_n))
    for s, switch in enumerate(SWITCH_S):
        k_sw = Clock(0.0, 0.0, switch).switch_epoch(ep)
        for a in range(a_n):
            x, p = ukf.prior()
            head = ukf.run(x, p, np.full(k_sw, ep.kappas[a]), 0, k_sw)
            for c in range(a_n):
                tail = ukf.run(x.copy(), p.copy(), np.full(n - k_sw, ep.kappas[c]), k_sw, n)
                out[s, a, c] = ukf.score(head + tail)
    return out


def tune(cfg: GyrosConfig, seeds: Sequence[int]) -> tuple[Clock, float]:
    """The clock of the grid with the lowest mean ``J`` over the episodes of ``seeds``."""
    return tune_on(cfg, [hs.episode(cfg, int(s)) for s in seeds])


def tune_on(cfg: GyrosConfig, episodes: Sequence[hs.Episode]) -> tuple[Clock, float]:
    """:func:`tune` on episodes drawn before."""
    kappas = np.asarray(cfg.environment.actions.values(), dtype=float)
    mean = np.mean([grid_scores(ep) for ep in episodes], axis=0)
    s, a, c = np.unravel_index(int(np.argmin(mean)), mean.shape)
    return Clock(float(kappas[a]), float(kappas[c]), SWITCH_S[s]), float(mean[s, a, c])


__all__ = ["SWITCH_S", "Clock", "grid_scores", "score", "tune", "tune_on"]
