r"""Hindsight: each trial's best κ schedule with that trial's truth known (a yardstick).

Not a flight method: it reads the truth of the very trial it filters. It answers "how low can
the judged metric go by choosing κ at all?" (docs/methods.md, "Hindsight"): no κ-scheduling
policy that decides every ``adaptive.hindsight.period_s`` from the action set can beat it on
that trial, up to the optimiser's own shortfall. ``kf-tuned → hindsight`` is the headroom a
policy can take a share of.

For trial ``b``, over schedules ``u ∈ {0 … A−1}^T`` held per decision period ``P``
(``κ(t_k) = κ_{u[k // P]}``, ``κ_a`` the action set)::

    u*_b ≈ argmin_u J_b(u),   J_b(u) = settled-window score of adaptive.tuned.metric
                                       of the filter run with κ(t) = κ_u(t)

(``state_settled`` by default: RMS over settled epochs and the 15 states of error / final
nominal CRLB; :mod:`..judging`). The search space has ``A^T`` points (11³⁶⁰ for a 3600 s run),
so ``argmin`` is approximated by coordinate descent over time blocks of decreasing length
(:mod:`.schedule_search`): start from the best constant κ of the trial (and any schedules a
caller passes as ``starts``), then for each block length of ``blocks_s`` and each block in
time order try every action over the block with the incumbent elsewhere, keep the best;
``passes`` sweeps per length. The score never increases from stage to stage; the result is a
local optimum, so the bound is an upper estimate of the true lower bound (a better start
or a finer search can only lower it).

Cost. A sweep at block length ``L`` costs about ``A N² / (2L)`` trial-epochs per trial (a
candidate runs from its block start to the end of the run): for a 3600 s run and 11 actions,
0.18 million at 400 s but 3.6 million at 20 s. So the block lengths halve from 400 s to 20 s
(400, 200, 100, 50, 20), and those shorter than ``focus_s`` (100 s) are *focused*: a trial
tries a block only within ``focus_s`` of a switch of its schedule (where κ changes) as the
longer lengths left it, which is where a shorter block can still move something. Measured on
4 trials of ``thermal_snap_random``: 3.1 million trial-epochs per trial, the same final
score as an unfocused 400/100/20 s search at 4.2 million (docs/methods.md, "Hindsight").

Output: the filter run with the schedule found (:func:`~.oracle.run_schedule`, covariance and
κ included); ``logs["hindsight_scores"]`` (B, S) the per-trial score after each stage and
``logs["hindsight_stages"]`` (S,) their names; a note with the mean score per stage and the
cost.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from qkf.transfer_alignment.adaptive import HindsightConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    action_values,
    decision_steps,
    uses_settings,
)
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.methods.schedule_search import SearchPlan, SearchResult, search
from qkf.transfer_alignment.scenario import ScenarioData


def hindsight_plan(cfg: Config) -> SearchPlan:
    """The search :mod:`..schedule_search` runs for ``adaptive.hindsight`` (block lengths in
    decision periods; ``ValueError`` for a block that is not a whole number of periods)."""
    hc = cfg.adaptive.hindsight
    period = decision_steps(hc.period_s, cfg.scenario.dt_s)
    period_s = period * cfg.scenario.dt_s
    blocks = []
    for block_s in hc.blocks_s:
        n = round(block_s / period_s)
        if n < 1 or abs(n * period_s - block_s) > 1e-6 * block_s:
            raise ValueError(
                f"adaptive.hindsight.blocks_s: {block_s:g} s is not a multiple of the "
                f"decision period ({period_s:g} s)"
            )
        blocks.append(n)
    reach = None if hc.focus_s is None else max(1, round(hc.focus_s / period_s))
    return SearchPlan(
        period=period,
        blocks=tuple(blocks),
        passes=hc.passes,
        pooled=False,
        metric=cfg.adaptive.tuned.metric,
        # a block shorter than focus_s is tried only near a switch; the longer ones everywhere
        focus=tuple(
            reach if hc.focus_s is not None and n * period_s < hc.focus_s - 1e-9 else None
            for n in blocks
        ),
        screen=None if hc.screen_s is None else decision_steps(hc.screen_s, cfg.scenario.dt_s),
        keep=hc.screen_keep,
    )


def convergence_note(res: SearchResult, metric: str, n_actions: int) -> str:
    """One line: mean score per stage and what the search spent."""
    stages = zip(res.stages, res.scores.mean(axis=0), strict=True)
    means = " → ".join(f"{m:.4g} ({st})" for st, m in stages)
    b = res.scores.shape[0]
    return (
        f"per-trial best κ schedule with the truth known ({n_actions} actions); mean {metric} "
        f"{means}; {res.runs / b:.0f} rollouts ({res.stopped / b:.0f} stopped once they could "
        f"not win), {res.trial_epochs / b:.3g} trial-epochs, "
        f"{res.seconds / b:.1f} s per trial (a yardstick, not a flight method)"
    )


RESTART_STREAM = 0x51A7
"""Part of every restart's seed: ``SeedSequence([run seed, trial, restart, RESTART_STREAM])``."""


def restart_schedule(cfg: Config, data: ScenarioData, restart: int) -> np.ndarray:
    """The random starting schedule of restart ``restart`` (1-based), κ per trial and epoch
    (B, N): one uniformly drawn action per ``blocks_s[0]``, per trial from its own seed."""
    values = action_values(cfg)
    block = decision_steps(cfg.adaptive.hindsight.blocks_s[0], cfg.scenario.dt_s)
    n_blocks = -(-data.n_epochs // block)
    out = np.empty((data.n_trials, data.n_epochs))
    for row, trial in enumerate(data.trial_ids.tolist()):
        rng = np.random.default_rng([data.seed, int(trial), restart, RESTART_STREAM])
        picks = values[rng.integers(values.size, size=n_blocks)]
        out[row] = np.repeat(picks, block)[: data.n_epochs]
    return out


def certificate(final: np.ndarray) -> np.ndarray:
    """Per trial, how far apart the searches' optima are (B,): ``(max_j J_j − min_j J_j) /
    min_j J_j`` over the searches ``final`` (B, S) (0 with one search, or when all agree)."""
    best = np.min(final, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = (np.max(final, axis=1) - best) / best
    return np.where(np.isfinite(spread), spread, 0.0)


def hindsight(cfg: Config, data: ScenarioData, starts: Sequence[np.ndarray] = ()) -> MethodOutput:
    """The hindsight schedule of every trial of ``data`` (module docstring).

    ``starts``: extra starting schedules, κ per trial and epoch (B, N) or (N,) (say a
    policy's or the oracle's κ), snapped to the decision periods and the action set; the
    search starts per trial from the best of the constants and these. Then
    ``adaptive.hindsight.restarts`` searches from random schedules (:func:`restart_schedule`);
    each trial keeps the best schedule of all searches.
    """
    plan = hindsight_plan(cfg)
    res = search(cfg, data, plan, starts)
    kappa, scores = res.kappa.copy(), [res.scores[:, -1]]
    restart_plan = replace(plan, constants=False)
    for r in range(1, cfg.adaptive.hindsight.restarts + 1):
        again = search(cfg, data, restart_plan, [restart_schedule(cfg, data, r)])
        better = again.scores[:, -1] < np.min(scores, axis=0)
        kappa[better] = again.kappa[better]
        scores.append(again.scores[:, -1])
    final = np.stack(scores, axis=1)  # (B, 1 + restarts)
    out = run_schedule(cfg, data, kappa)
    out.logs["hindsight_scores"] = res.scores
    out.logs["hindsight_stages"] = np.array(res.stages)
    out.logs["hindsight_searches"] = final
    out.notes["hindsight"] = convergence_note(res, plan.metric, action_values(cfg).size)
    if final.shape[1] > 1:
        spread = certificate(final)
        gain = (final[:, 0] - final.min(axis=1)) / final.min(axis=1)
        out.notes["hindsight_certificate"] = (
            f"best κ schedule found: the best of {final.shape[1]} searches per trial (one "
            f"from the best constant, {final.shape[1] - 1} from random schedules); their optima "
            f"differ by {100 * np.median(spread):.2g} % (median over trials), "
            f"{100 * np.max(spread):.2g} % at most; the restarts improved on the first search "
            f"by {100 * np.mean(gain):.2g} % on average, on {int(np.sum(gain > 0))} of "
            f"{gain.size} trials"
        )
    return out


@uses_settings("hindsight", HindsightConfig, reads=("tuned",))
class Hindsight:
    """The ``hindsight`` yardstick: nothing to prepare (each trial is searched on its own)."""

    def __call__(
        self, cfg: Config, data: ScenarioData, starts: Sequence[np.ndarray] = ()
    ) -> MethodOutput:
        return hindsight(cfg, data, starts)


run_hindsight = Hindsight()
