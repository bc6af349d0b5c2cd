r"""Search for the best piecewise-constant κ schedule with the truth known (the engine of the
``hindsight`` and ``clock`` yardsticks, docs/methods.md).

A schedule holds one action of the set ``{κ_a}`` (:func:`~.base.action_values`) per *period* of
``P`` epochs: ``κ(t_k) = κ_{u[k // P]}``, ``u ∈ {0 … A−1}^T``, ``T = ⌈N / P⌉``. Its cost for
trial ``b`` is the settled-window score of the filter run with it (:mod:`..judging`)::

    J_b(u) = sqrt( S_b(u) / (N_s · n) ),  S_b(u) = Σ_{k settled} Σ_{i ∈ states} (e_{b,k,i} / w_i)²

(``N_s`` settled epochs of the trial's own window, ``n`` states of the metric, ``w`` the
metric's weights: the trial's final CRLB for ``state_settled``, 1 for a group metric;
:mod:`qkf.transfer_alignment.settled`). Two criteria: *per trial*, each
trial has its own schedule and minimises its own ``J_b`` (hindsight); *pooled*, one schedule
for all trials minimises ``sqrt(mean_b J_b²)`` (clock; infinite if a trial diverges).

Coordinate descent over time blocks. Start from the best of the constant schedules and any
given starting schedules (one batched run from t = 0). Then for each block length ``L`` (in
periods, coarse to fine), ``passes`` sweeps; a sweep visits the blocks ``[jL, (j+1)L)`` in
time order and for each tries every action held over the block, the incumbent schedule
everywhere else, keeping the best if it is strictly better than the incumbent (ties keep the
incumbent, so the score never increases). Why it is affordable:

* the schedule before the block is the incumbent's, so the filter state at the block start is
  shared by every candidate: an incumbent filter is carried forward block by block and
  replicated into one row per (trial, candidate); a candidate costs ``N − s`` epochs from
  the block start ``s``, not ``N``;
* the sum ``S`` over the settled epochs before ``s`` is the incumbent's, accumulated while
  carrying it; a candidate adds its own from ``s`` on;
* all (trial, candidate) rows run in one batched filter, in chunks of epochs (bounded memory);
* a candidate equal to the incumbent over the block is not run (its score is known), and in
  later passes at one block length a trial whose previous pass changed nothing is left out
  (the pass would repeat it exactly).

A sweep at block length ``L`` epochs costs about ``A N² / (2L)`` trial-epochs per trial.
``focus`` restricts a block length to blocks near a switch of the incumbent (where it
changes action): the fine lengths then sharpen the switching times the coarse ones found
instead of revisiting long constant stretches (see :func:`search`).

The errors are :func:`~qkf.transfer_alignment.metrics.state_errors` (attitude
``δθ = Log(Ĉᵀ C_true)``, ``Δb = b − b̂``, ``Δp = p − p̂``), one compiled call per chunk of the
millions of epochs the search evaluates; the scores agree with
:func:`~qkf.transfer_alignment.judging.estimate_scores` to rounding (the order of the sums).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from qkf.core.montecarlo import progress_stage
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.judging import METRIC_STATES, STATE_METRIC, pooled
from qkf.transfer_alignment.methods.base import action_values, new_filter, per_epoch
from qkf.transfer_alignment.metrics import state_errors
from qkf.transfer_alignment.scenario import ScenarioData
from qkf.transfer_alignment.settled import settled_windows

ROW_EPOCHS = 100_000
"""Rows × epochs per filter call of a rollout: the chunk length is this over the row count
(about 70 MB of records and inputs), so the memory does not grow with the batch."""


@dataclass(frozen=True)
class SearchPlan:
    """What :func:`search` optimises and how.

    ``period``: epochs per schedule period; ``blocks``: block lengths in periods, visited in
    this order (coarse to fine); ``passes``: sweeps per block length; ``pooled``: one schedule
    for all trials (else one per trial); ``metric``: the judged metric
    (:func:`~qkf.transfer_alignment.judging.trial_scores`); ``focus``: per block length,
    ``None`` (every block) or a reach in periods: only blocks within it of a switch of the
    incumbent (lengths beyond the tuple: every block); ``stop_early``: in a per-trial search,
    stop a candidate as soon as it cannot beat its trial's incumbent (the same result, fewer
    epochs filtered; :meth:`_Search.rollout`); ``screen``: in a per-trial search, run every
    candidate only ``screen`` epochs past its block, then carry on to the end only the
    ``keep`` of each trial whose sums are lowest by then (None: every candidate to the end);
    ``constants``: start from the best of the constant schedules and the given starts (else
    from the starts alone: a restart of :mod:`..hindsight`).
    Screening is a heuristic: a candidate behind at the screen and ahead at the end is missed
    (the filter forgets the block's κ within a few hundred seconds, so it is rare; measured in
    docs/methods.md, "Hindsight").
    """

    period: int
    blocks: tuple[int, ...]
    passes: int = 1
    pooled: bool = False
    metric: str = STATE_METRIC
    focus: tuple[int | None, ...] = ()
    stop_early: bool = True
    screen: int | None = None
    keep: int = 3
    constants: bool = True  # start from the best of the constants and the starts (else starts)


@dataclass
class SearchResult:
    """The schedule found and how the search got there.

    ``choice`` (B, T): action index per trial and period (pooled: the same row for every
    trial); ``kappa`` (B, N): κ per epoch; ``stages``: ``"start"``, then ``"<L> s #<pass>"``
    per sweep; ``scores`` (B, S): each trial's score after each stage (the metric's units);
    ``runs``: rollouts (one trial and candidate from a block start to the end of the run);
    ``trial_epochs``: filter trial-epochs spent (rollouts and the carried incumbent);
    ``seconds``: wall time; ``stopped``: rollouts stopped before the end of the run because
    they could no longer beat the incumbent.
    """

    choice: np.ndarray
    kappa: np.ndarray
    stages: tuple[str, ...]
    scores: np.ndarray
    runs: int
    trial_epochs: int
    seconds: float
    stopped: int = 0
    screened: int = 0

    def pooled_scores(self) -> np.ndarray:
        """RMS over trials of the score after each stage (S,)."""
        return np.array([pooled(self.scores[:, i]) for i in range(self.scores.shape[1])])


class _Scorer:
    """Sums ``S`` of squared weighted errors over each trial's settled epochs in a chunk, per
    row, divided by the trial's count of terms ``N_s,b · n`` (so ``J = sqrt(S)``: trials have
    windows of their own length, :mod:`qkf.transfer_alignment.settled`)."""

    def __init__(self, cfg: Config, data: ScenarioData, metric: str) -> None:
        windows = settled_windows(cfg, data)
        if metric == STATE_METRIC:
            self.states: slice = slice(0, 15)
            weights = windows.weights
        elif metric in METRIC_STATES:
            self.states = METRIC_STATES[metric]
            weights = np.ones((data.n_trials, 15))
        else:
            known = ", ".join([STATE_METRIC, *METRIC_STATES])
            raise ValueError(f"unknown metric {metric!r}; known: {known}")
        inv_w = 1.0 / weights[:, self.states]  # (B, n)
        count = (data.n_epochs - windows.first) * inv_w.shape[1]  # N_s,b · n
        self.scale = inv_w / np.sqrt(count)[:, None]
        self.first = windows.first
        self.data = data

    def chunk(self, est: np.ndarray, trials: np.ndarray, k0: int) -> np.ndarray:
        """``Σ`` over the settled epochs of ``est`` (R, n, 16), which covers epochs
        ``[k0, k0 + n)`` of the rows' ``trials`` (R,); NaN for a row whose errors are not
        finite there."""
        first = self.first[trials]
        skip = max(0, int(first.min()) - k0)
        n = est.shape[1]
        if skip >= n:
            return np.zeros(est.shape[0])
        sl = slice(k0 + skip, k0 + n)
        d = self.data
        err = state_errors(
            est[:, skip:], d.q_true[trials, sl], d.bias[trials, sl], d.calib[trials, sl]
        )
        per_epoch = np.sum((err[..., self.states] * self.scale[trials][:, None, :]) ** 2, axis=2)
        settled = np.arange(k0 + skip, k0 + n)[None, :] >= first[:, None]
        return np.sum(np.where(settled, per_epoch, 0.0), axis=1)

    def score(self, total: np.ndarray) -> np.ndarray:
        """``J`` from ``S``; ``inf`` where ``S`` is not finite (a lost trial never wins)."""
        with np.errstate(invalid="ignore"):
            j = np.sqrt(total)
        return np.where(np.isfinite(j), j, np.inf)


class _Search:
    """One search over the trials of ``data`` (state shared by the stages)."""

    def __init__(self, cfg: Config, data: ScenarioData, plan: SearchPlan) -> None:
        self.cfg, self.data, self.plan = cfg, data, plan
        self.values = action_values(cfg)
        self.scorer = _Scorer(cfg, data, plan.metric)
        n = data.n_epochs
        self.n_periods = -(-n // plan.period)
        self.period_of = np.arange(n) // plan.period  # period index of each epoch
        self.runs = 0
        self.trial_epochs = 0
        self.stopped = 0  # candidate rollouts stopped early (they could not beat the incumbent)
        self.screened = 0  # candidate rollouts dropped at the screen (plan.screen)

    # --- filter runs -------------------------------------------------------------------

    def _kappa(self, sched: np.ndarray, k0: int, k1: int) -> np.ndarray:
        return self.values[sched[:, self.period_of[k0:k1]]]

    def _inputs(
        self, trials: np.ndarray | slice, k0: int, k1: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        d = self.data
        sl = slice(k0, k1)
        meas = d.has_meas[sl] if d.has_meas.ndim == 1 else d.has_meas[trials, sl]
        return d.gyro[trials, sl], d.ads_q[trials, sl], d.ads_rate[trials, sl], meas

    def rollout(
        self,
        carry: TransferAlignmentKF,
        trials: np.ndarray,
        sched: np.ndarray,
        start: int,
        stop_at: tuple[np.ndarray, np.ndarray] | None = None,
        screen_at: int | None = None,
    ) -> np.ndarray:
        """``S`` over the settled epochs in ``[start, N)`` of rows that start from the carried
        filter's trial ``trials[r]`` (rows of a trial adjacent) and follow ``sched[r]`` (R, T).

        ``stop_at = (offset, bound)`` (R,) each: a row is stopped, and its ``S`` is ``inf``, as
        soon as ``offset + S`` so far reaches ``bound`` (checked between chunks of epochs).
        ``S`` only grows, and the sum and the score are monotone in floating point, so a
        stopped row could not have ended below ``bound``: a search that stops candidates at
        the incumbent's ``S`` takes exactly the decisions it takes without stopping them.
        ``screen_at``: the epoch at which each trial keeps only its ``plan.keep`` rows of
        lowest ``S`` so far (the others: ``inf``).
        """
        rows, n = trials.size, self.data.n_epochs
        kf = TransferAlignmentKF(carry.params, rows)
        # one load per trial: its rows are adjacent, and a one-row slice broadcasts over them
        edges = np.flatnonzero(np.diff(trials)) + 1
        for r0, r1 in zip([0, *edges.tolist()], [*edges.tolist(), rows], strict=True):
            b = int(trials[r0])
            kf.load_trial(slice(r0, r1), carry, slice(b, b + 1))
        total = np.zeros(rows)
        live = np.arange(rows)  # the row of each filter row (rows stopped early drop out)
        chunk = int(np.clip(ROW_EPOCHS // rows, 50, 600))
        cuts = set(range(start, n, chunk)) | {n}
        if screen_at is not None and start < screen_at < n:
            cuts.add(screen_at)
        bounds = sorted(cuts)
        for k0, k1 in itertools.pairwise(bounds):
            on = trials[live]
            rec = kf.step(*self._inputs(on, k0, k1), self._kappa(sched[live], k0, k1))
            total[live] += self.scorer.chunk(rec.est, on, k0)
            self.trial_epochs += live.size * (k1 - k0)
            if k1 == n:
                break
            over = np.zeros(live.size, dtype=bool)
            if stop_at is not None:
                offset, bound = stop_at
                over = offset[live] + total[live] >= bound[live]  # False for NaN: never stopped
            if k1 == screen_at:
                behind = ~_lowest_per_group(on, total[live], self.plan.keep)
                self.screened += int((behind & ~over).sum())
                over |= behind
            if over.any():
                self.stopped += int(over.sum())
                kf, live = drop_rows(kf, total, live, over)
                if live.size == 0:
                    break
        if live.size:
            total[live[kf.diverged]] = np.nan
        self.runs += rows
        return total

    def advance(
        self, carry: TransferAlignmentKF, sched: np.ndarray, k0: int, k1: int
    ) -> np.ndarray:
        """Carry the incumbent filters (all trials) over ``[k0, k1)``; ``S`` of those epochs."""
        rec = carry.step(*self._inputs(slice(None), k0, k1), self._kappa(sched, k0, k1))
        self.trial_epochs += carry.n_trials * (k1 - k0)
        return self.scorer.chunk(rec.est, np.arange(carry.n_trials), k0)

    # --- choosing -----------------------------------------------------------------------

    def pick(self, cand: np.ndarray, incumbent: np.ndarray) -> np.ndarray:
        """Per trial, the option to take (−1: keep the incumbent) from candidate scores
        (B, O) (``inf`` where not run) and the incumbent's scores (B,)."""
        if self.plan.pooled:
            totals = [pooled(cand[:, o]) for o in range(cand.shape[1])]
            best = int(np.argmin(totals))
            # strictly better only: a tie keeps the incumbent
            take = best if totals[best] < pooled(incumbent) else -1
            return np.full(cand.shape[0], take)
        best = np.argmin(cand, axis=1)
        better = cand[np.arange(cand.shape[0]), best] < incumbent
        return np.where(better, best, -1)

    def start(self, starts: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The best of the constant schedules and ``starts`` (each (B, T) action indices):
        ``(choice (B, T), scores (B,), S (B,))``."""
        b, t, a = self.data.n_trials, self.n_periods, self.values.size
        constants = [np.full((b, t), i) for i in range(a)] if self.plan.constants else []
        options = constants + [np.asarray(s) for s in starts]
        if not options:
            raise ValueError("a search without the constants needs a starting schedule")
        o = len(options)
        trials = np.repeat(np.arange(b), o)  # trial-major: a trial's rows adjacent
        sched = np.stack(options, axis=1).reshape(b * o, t)
        carry = new_filter(self.cfg, self.data)
        total = self.rollout(carry, trials, sched, 0).reshape(b, o)
        cand = self.scorer.score(total)
        if self.plan.pooled:
            best = np.full(b, int(np.argmin([pooled(cand[:, i]) for i in range(o)])))
        else:
            best = np.argmin(cand, axis=1)
        rows = np.arange(b)
        return np.stack(options, axis=1)[rows, best], cand[rows, best], total[rows, best]

    def sweep(
        self,
        choice: np.ndarray,
        score: np.ndarray,
        total: np.ndarray,
        length: int,
        want: np.ndarray,
    ) -> np.ndarray:
        """One pass over the blocks of ``length`` periods, in place on ``choice``, ``score``
        and the incumbents' ``S`` (``total``); trial ``i`` tries a block only if ``want[i]``
        (B, T) holds for one of its periods. Returns which trials changed (B,). In a
        per-trial search a candidate stops as soon as it cannot beat its trial's incumbent
        (:meth:`rollout`)."""
        b, a, p = self.data.n_trials, self.values.size, self.plan.period
        n = self.data.n_epochs
        changed = np.zeros(b, dtype=bool)
        carry = new_filter(self.cfg, self.data)
        prefix = np.zeros(b)  # S of the incumbent before the block start
        for p0 in range(0, self.n_periods, length):
            p1 = min(self.n_periods, p0 + length)
            k0, k1 = p0 * p, min(n, p1 * p)
            tries = np.any(want[:, p0:p1], axis=1)
            block = choice[:, p0:p1]
            same = (block == block[:, :1]).all(axis=1)
            # (trial, action) rows; the incumbent's own action over the block is known
            run = tries[:, None] & ~(same[:, None] & (block[:, :1] == np.arange(a)))
            trials, actions = np.nonzero(run)  # trial-major
            if trials.size:
                sched = choice[trials].copy()
                sched[:, p0:p1] = actions[:, None]
                early = self.plan.stop_early and not self.plan.pooled
                stop_at = (prefix[trials], total[trials]) if early else None
                screen = self.plan.screen
                screen_at = None if screen is None or self.plan.pooled else k1 + screen
                tried = prefix[trials] + self.rollout(carry, trials, sched, k0, stop_at, screen_at)
                cand = np.full((b, a), np.inf)
                cand[trials, actions] = self.scorer.score(tried)
                sums = np.full((b, a), np.nan)
                sums[trials, actions] = tried
                if self.plan.pooled:  # every trial needs its row for a pooled score
                    cand[:, ~run.all(axis=0)] = np.inf
                take = self.pick(cand, score)
                for i in np.flatnonzero(take >= 0):
                    choice[i, p0:p1] = take[i]
                    score[i] = cand[i, take[i]]
                    total[i] = sums[i, take[i]]
                    changed[i] = True
            prefix += self.advance(carry, choice, k0, k1)
        return changed


def drop_rows(
    kf: TransferAlignmentKF, total: np.ndarray, live: np.ndarray, over: np.ndarray
) -> tuple[TransferAlignmentKF, np.ndarray]:
    """Stop the filter rows ``over`` (of the ``live`` ones) of a rollout: their ``total`` is
    ``inf`` (they cannot win), and the filter goes on with the others only. Returns the
    smaller filter and the rows still live."""
    total[live[over]] = np.inf
    keep = np.flatnonzero(~over)
    rest = TransferAlignmentKF(kf.params, max(keep.size, 1))
    if keep.size:
        rest.load_trial(slice(None), kf, keep)  # type: ignore[arg-type]
    return rest, live[keep]


def _lowest_per_group(groups: np.ndarray, values: np.ndarray, keep: int) -> np.ndarray:
    """Per row, whether it is among the ``keep`` lowest ``values`` of its group (rows of a
    group adjacent; ties: the earlier row; NaN, a lost row, ranks last)."""
    order = np.lexsort((np.arange(values.size), np.nan_to_num(values, nan=np.inf), groups))
    ranked = groups[order]
    starts = np.flatnonzero(np.r_[True, ranked[1:] != ranked[:-1]])
    rank = np.arange(values.size) - np.repeat(starts, np.diff(np.r_[starts, values.size]))
    out = np.empty(values.size, dtype=bool)
    out[order] = rank < keep
    return out


def switches(row: np.ndarray, reach: int) -> np.ndarray:
    """Periods (T,) within ``reach`` periods of a switch of the schedule ``row`` (T,) of
    action indices: a period whose action differs from the one before it."""
    t = row.size
    near = np.zeros(t, dtype=bool)
    for i in np.flatnonzero(np.diff(row) != 0) + 1:
        near[max(0, i - reach) : min(t, i + reach)] = True
    return near


def search(
    cfg: Config,
    data: ScenarioData,
    plan: SearchPlan,
    starts: Sequence[np.ndarray] = (),
    progress_label: str | None = None,
) -> SearchResult:
    """Coordinate descent for the best schedule (module docstring).

    ``starts``: extra starting schedules, κ per trial and epoch (B, N) or (N,); each is
    snapped to the schedule grid (its value at each period's first epoch, rounded to the
    nearest action in log κ). In a pooled search a start must be the same for every trial.
    ``focus`` (:class:`SearchPlan`): at a block length with a reach, a block is visited
    only if it lies within that many periods of a switch of the incumbent as it stands when
    that length begins (per trial in a per-trial search). ``progress_label``:
    a counted row under a benchmark's progress bar, one step per sweep.
    """
    t0 = time.perf_counter()
    s = _Search(cfg, data, plan)
    b, t = data.n_trials, s.n_periods
    grid = [snap(cfg, np.broadcast_to(k, (b, data.n_epochs)), plan.period) for k in starts]
    if plan.pooled and any((g != g[:1]).any() for g in grid):
        raise ValueError("a pooled search needs starting schedules shared by every trial")
    advance = (
        progress_stage(progress_label, 1 + len(plan.blocks) * plan.passes, "sweeps")
        if progress_label
        else _no_progress
    )
    choice, score, total = s.start(grid)
    stages, scores = ["start"], [score.copy()]
    advance(1)
    for level, length in enumerate(plan.blocks):
        reach = plan.focus[level] if level < len(plan.focus) else None
        if reach is None:
            want = np.ones((b, t), dtype=bool)
        elif plan.pooled:
            want = np.broadcast_to(switches(choice[0], reach), (b, t)).copy()
        else:
            want = np.stack([switches(row, reach) for row in choice])
        for rep in range(plan.passes):
            if want.any():
                changed = s.sweep(choice, score, total, length, want)
                # a trial that a pass left unchanged would only repeat it exactly
                want &= changed[:, None]
            stages.append(f"{length * plan.period * data.dt:g} s #{rep + 1}")
            scores.append(score.copy())
            advance(1)
    return SearchResult(
        choice=choice,
        kappa=per_epoch(s.values[choice], plan.period, data.n_epochs),
        stages=tuple(stages),
        scores=np.stack(scores, axis=1),
        runs=s.runs,
        trial_epochs=s.trial_epochs,
        seconds=time.perf_counter() - t0,
        stopped=s.stopped,
        screened=s.screened,
    )


def snap(cfg: Config, kappa: np.ndarray, period: int) -> np.ndarray:
    """A κ schedule (B, N) on the search grid: action indices (B, T) of the value at each
    period's first epoch, the nearest action in log κ."""
    log_actions = np.log(action_values(cfg))
    first = np.asarray(kappa, dtype=float)[:, ::period]
    if not np.all(np.isfinite(first) & (first > 0.0)):
        raise ValueError("a starting schedule must be finite and positive")
    return np.argmin(np.abs(np.log(first)[..., None] - log_actions), axis=-1)


def _no_progress(n: int = 1) -> None:
    """``advance`` when no progress row is wanted."""
