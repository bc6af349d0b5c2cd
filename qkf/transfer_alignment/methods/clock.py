r"""Clock: the best open-loop κ(t), one schedule of time for every trial (a yardstick).

Not a flight method in spirit: it is tuned with the truth (on the tuning seeds, like
``kf-tuned``), and it knows nothing of the trial it filters but the clock. It answers "how
much of the headroom is just *when* in the run to open the filter up?" (docs/methods.md,
"Clock"): a feedback policy that beats it uses what it observes, not only the time.

The schedule is piecewise constant on blocks of ``adaptive.clock.block_s`` from t = 0, one
action of the set ``{κ_a}`` per block::

    κ(t) = κ_{u[j]}   for  j · block_s ≤ t < (j + 1) · block_s
    u*   ≈ argmin_u  sqrt( mean over tuning trials b of J_b(u)² )

with ``J_b`` the settled-window score of ``adaptive.tuned.metric`` (:mod:`..judging`) on
``adaptive.tuned.trials`` trials of seed ``adaptive.tuned.seed`` (infinite if a trial
diverges). The search is :mod:`.schedule_search` in its pooled form: start from the best
constant κ (the ``kf-tuned`` choice, so the clock's tuning score is never above kf-tuned's),
then ``passes`` sweeps of coordinate descent over the blocks in time order, each block trying
every action with the rest of the schedule held.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.adaptive import ClockConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    action_values,
    decision_steps,
    uses_settings,
)
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.methods.schedule_search import SearchPlan, search
from qkf.transfer_alignment.scenario import ScenarioData, simulate


@dataclass(frozen=True)
class ClockSchedule:
    """An open-loop κ(t) fixed beforehand (what :class:`Clock` prepares): ``kappa[j]`` from
    ``j · block_s`` to ``(j + 1) · block_s`` (s), the last value to the end of any run.

    ``tuning`` holds the pooled tuning score after each stage of the search (``stages``).
    """

    block_s: float
    kappa: tuple[float, ...]
    note: str = ""
    stages: tuple[str, ...] = ()
    tuning: tuple[float, ...] = ()

    def at(self, t: np.ndarray) -> np.ndarray:
        """κ at times ``t`` (s)."""
        j = np.floor(np.asarray(t, dtype=float) / self.block_s + 1e-9).astype(int)
        return np.asarray(self.kappa)[np.clip(j, 0, len(self.kappa) - 1)]

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        kappa = np.broadcast_to(self.at(data.t), (data.n_trials, data.n_epochs))
        out = run_schedule(cfg, data, np.ascontiguousarray(kappa))
        if self.note:
            out.notes["clock"] = self.note
        return out


def describe(block_s: float, kappa: tuple[float, ...]) -> str:
    """``κ = 40 for 0–300 s, 0.4 from 300 s``: runs of equal blocks merged."""
    parts = []
    j = 0
    while j < len(kappa):
        end = j
        while end + 1 < len(kappa) and kappa[end + 1] == kappa[j]:
            end += 1
        span = (
            f"from {j * block_s:g} s"
            if end == len(kappa) - 1
            else f"for {j * block_s:g}–{(end + 1) * block_s:g} s"
        )
        parts.append(f"{kappa[j]:.3g} {span}")
        j = end + 1
    return "κ = " + ", ".join(parts)


def tune_clock(cfg: Config, progress_label: str = "tune clock") -> ClockSchedule:
    """The pooled coordinate-descent search on the tuning trials (module docstring).

    ``progress_label``: the progress row it shows, one step per sweep, while a benchmark's
    progress bar is open.
    """
    cc, tc = cfg.adaptive.clock, cfg.adaptive.tuned
    period = decision_steps(cc.block_s, cfg.scenario.dt_s)
    block_s = period * cfg.scenario.dt_s  # a whole number of epochs: what the search used
    data = simulate(cfg, tc.seed, tc.trials)
    plan = SearchPlan(period=period, blocks=(1,), passes=cc.passes, pooled=True, metric=tc.metric)
    res = search(cfg, data, plan, progress_label=progress_label)
    kappa = tuple(float(k) for k in action_values(cfg)[res.choice[0]])
    tuning = tuple(float(v) for v in res.pooled_scores())
    note = (
        f"{describe(block_s, kappa)} (open loop; tuned with the truth on {tc.trials} trials "
        f"of seed {tc.seed}: {tc.metric} {tuning[0]:.4g} constant → {tuning[-1]:.4g})"
    )
    return ClockSchedule(block_s, kappa, note, res.stages, tuning)


@uses_settings("clock", ClockConfig, reads=("tuned",))
class Clock:
    """The ``clock`` yardstick: tuned once per benchmark in :meth:`prepare` (driver process);
    called unprepared it tunes on the spot."""

    def prepare(self, cfg: Config) -> ClockSchedule:
        return tune_clock(cfg)

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return self.prepare(cfg)(cfg, data)


run_clock = Clock()
