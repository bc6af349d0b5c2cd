r"""Hindsight over the filter's moves: each trial's best schedule of κ *and* the other moves of
a v4 action space, with that trial's truth known (docs/methods.md, "Hindsight over the moves").

``hindsight-moves:CONTROLS`` (``CONTROLS`` as the environment's ``controls=``, e.g.
``kappa+reset+r_scale``) is the yardstick of policies that act in that space, as ``hindsight``
is of κ-only policies: it reads the truth of the very trial it filters. Per trial ``b`` it
approximates ``argmin J_b`` over move schedules held per decision period
(``adaptive.hindsight.period_s``), ``J_b`` the settled-window score of
``adaptive.tuned.metric`` (per-trial windows and weights, :mod:`..settled`), by coordinate
descent in stages, each of which can only lower ``J_b``:

1. **κ**: the κ-only hindsight schedule (:func:`.hindsight.hindsight`, its restarts included)
   when κ is controlled; else κ stays nominal.
2. **Constant factors**: for each of ``r_scale``, ``q_att``, ``q_bias`` that is controlled,
   every value of its grid held over the whole run, the others at the incumbent; the best
   is kept if it lowers ``J_b``.
3. **Resets** (``reset`` controlled): every reset size of the grid at every
   :data:`RESET_EVERY`-th period, one at a time on top of the incumbent (each candidate runs
   from its period to the end, from the incumbent's filter state there); the best is kept if
   it lowers ``J_b``; repeated up to :data:`MAX_RESETS` times.

The result is a local optimum, so the bound is an upper estimate of the true lower bound, as
for ``hindsight``: κ is searched first with the other moves nominal, and the moves are then
held constant (factors) or sparse (resets). Stage scores are logged (``hindsight_moves_scores``
(B, S)), and the certificate of the κ stage (its restarts' spread) is carried over.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.adaptive import HindsightConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    decision_steps,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.methods.hindsight import hindsight
from qkf.transfer_alignment.methods.moves_schedule import MoveSchedule, run_moves
from qkf.transfer_alignment.methods.schedule_search import _Scorer, drop_rows
from qkf.transfer_alignment.moves import BLOCK_SCALES, R_SCALES, RESET_FRACTIONS, apply_moves
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import ScenarioData

RESET_EVERY = 3
"""Stage 3 tries a reset every this many decision periods (30 s at the default 10-s period)."""
MAX_RESETS = 2
"""Stage 3 keeps at most this many resets per trial."""
CONTROL_MOVES = {
    "kappa": ("kappa",),
    "blocks": ("q_att", "q_bias", "kappa"),
    "reset": ("reset",),
    "r_scale": ("r_scale",),
    "r_step": ("r_scale",),  # a persistent r: every constant r is reachable by steps
    "kappa_step": ("kappa",),
}
"""The moves each control of the environments governs (as ``envs`` declares them)."""
FACTOR_GRIDS = {"r_scale": R_SCALES, "q_att": BLOCK_SCALES, "q_bias": BLOCK_SCALES}


def controlled_moves(controls: str) -> tuple[str, ...]:
    """The moves of a ``controls`` string (``ValueError`` for an unknown control)."""
    names = [c.strip() for c in controls.split("+")]
    unknown = [c for c in names if c not in CONTROL_MOVES]
    if unknown:
        raise ValueError(f"unknown control {unknown[0]!r}; known: {', '.join(CONTROL_MOVES)}")
    return tuple(dict.fromkeys(m for c in names for m in CONTROL_MOVES[c]))


class _Runner:
    """Runs candidate move schedules of rows (trial, candidate) and scores them."""

    def __init__(self, cfg: Config, data: ScenarioData, period: int) -> None:
        self.cfg, self.data, self.period = cfg, data, period
        self.scorer = _Scorer(cfg, data, cfg.adaptive.tuned.metric)
        self.n_periods = -(-data.n_epochs // period)
        self.trial_epochs = 0
        self.params = FilterParams.from_config(cfg)

    def run(
        self,
        trials: np.ndarray,
        sched: MoveSchedule,
        start: int = 0,
        carry: TransferAlignmentKF | None = None,
        bound: np.ndarray | None = None,
    ) -> np.ndarray:
        """``S`` from period ``start`` to the end of rows following ``sched`` (rows × T), each
        starting from trial ``trials[r]``'s state in ``carry`` (a fresh filter at start 0). A
        row whose ``S`` reaches ``bound[r]`` is stopped (``inf``): ``S`` only grows."""
        d, p = self.data, self.period
        rows = trials.size
        kf = TransferAlignmentKF(self.params, rows)
        if carry is None:
            kf.initialize(d.ads_q[trials, 0])
        else:
            for r in range(rows):
                kf.load_trial(r, carry, int(trials[r]))
        total = np.zeros(rows)
        live = np.arange(rows)
        # the filter is stepped in spans between periods where some row resets or changes a
        # factor; κ varies per epoch inside a span
        fields = sched.fields()
        change = np.zeros(self.n_periods, dtype=bool)
        change[start] = True
        for f in fields[1:]:
            change[1:] |= np.any(f[:, 1:] != f[:, :-1], axis=0)
        change |= np.any(sched.reset > 0.0, axis=0)
        cuts = [q for q in range(start, self.n_periods) if change[q]]
        cuts += list(range(start, self.n_periods, 30))  # chunks for early stopping
        spans = [*sorted(set(cuts)), self.n_periods]
        for q0, q1 in itertools.pairwise(spans):
            k0, k1 = q0 * p, min(d.n_epochs, q1 * p)
            apply_moves(kf, sched.at(q0, live))  # the moves of the span's first period
            kappa = np.repeat(sched.kappa[live, q0:q1], p, axis=1)[:, : k1 - k0]
            on = trials[live]
            sl = slice(k0, k1)
            meas = d.has_meas[sl] if d.has_meas.ndim == 1 else d.has_meas[on, sl]
            rec = kf.step(d.gyro[on, sl], d.ads_q[on, sl], d.ads_rate[on, sl], meas, kappa)
            total[live] += self.scorer.chunk(rec.est, on, k0)
            self.trial_epochs += live.size * (k1 - k0)
            if bound is not None and q1 < self.n_periods:
                over = total[live] >= bound[live]
                if over.any():
                    kf, live = drop_rows(kf, total, live, over)
                    if live.size == 0:
                        break
        if live.size:
            total[live[kf.diverged]] = np.nan
        return total

    def snapshots(
        self, sched: MoveSchedule, every: int
    ) -> tuple[dict[int, TransferAlignmentKF], dict[int, np.ndarray]]:
        """The incumbents' filter states at the start of every ``every``-th period (before that
        period's moves) and their ``S`` before it."""
        d, p = self.data, self.period
        kf = new_filter(self.cfg, d)
        states: dict[int, TransferAlignmentKF] = {}
        prefix: dict[int, np.ndarray] = {}
        s = np.zeros(d.n_trials)
        for q in range(self.n_periods):
            if q % every == 0:
                states[q], prefix[q] = kf.copy(), s.copy()
            k0, k1 = q * p, min(d.n_epochs, (q + 1) * p)
            kappa = apply_moves(kf, sched.at(q))
            sl = slice(k0, k1)
            rec = kf.step(d.gyro[:, sl], d.ads_q[:, sl], d.ads_rate[:, sl],
                          d.has_meas[..., sl], kappa)  # fmt: skip
            s += self.scorer.chunk(rec.est, np.arange(d.n_trials), k0)
            self.trial_epochs += d.n_trials * (k1 - k0)
        return states, prefix


def _take(sched: MoveSchedule, rows: np.ndarray, cand: MoveSchedule, pick: np.ndarray) -> None:
    """Copy candidate rows ``pick`` into the incumbent's trials ``rows``, in place."""
    for mine, theirs in zip(sched.fields(), cand.fields(), strict=True):
        mine[rows] = theirs[pick]


def _candidates(sched: MoveSchedule, trials: np.ndarray) -> MoveSchedule:
    """Copies of the incumbent's rows of ``trials`` (to be edited)."""
    return MoveSchedule(sched.period, *(np.array(f[trials]) for f in sched.fields()))


@dataclass(frozen=True)
@uses_settings("hindsight", HindsightConfig, reads=("tuned",))
class HindsightMoves:
    """``hindsight-moves:CONTROLS`` (module docstring)."""

    controls: str

    @property
    def default_label(self) -> str:
        return f"hindsight-moves:{self.controls}"

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        moves = controlled_moves(self.controls)
        period = decision_steps(cfg.adaptive.hindsight.period_s, cfg.scenario.dt_s)
        runner = _Runner(cfg, data, period)
        b, t = data.n_trials, runner.n_periods
        notes: dict[str, str] = {}
        if "kappa" in moves:  # stage 1: the κ-only hindsight
            first = hindsight(cfg, data)
            assert first.kappa is not None
            kappa = first.kappa[:, ::period]
            notes.update({k: v for k, v in first.notes.items() if k.startswith("hindsight")})
        else:
            nominal = cfg.adaptive.actions.values()[cfg.adaptive.actions.nominal_index()]
            kappa = np.full((b, t), float(nominal))
        sched = MoveSchedule.nominal(period, kappa)
        rows = np.arange(b)
        score = runner.scorer.score(runner.run(rows, sched))
        stages, scores = ["kappa"], [score.copy()]
        for name in ("r_scale", "q_att", "q_bias"):  # stage 2: constant factors
            if name not in moves:
                continue
            grid = np.asarray(FACTOR_GRIDS[name])
            trials = np.repeat(rows, grid.size)
            cand = _candidates(sched, trials)
            getattr(cand, name)[:] = np.tile(grid, b)[:, None]
            j = runner.scorer.score(runner.run(trials, cand)).reshape(b, grid.size)
            best = np.argmin(j, axis=1)
            better = j[rows, best] < score
            _take(sched, rows[better], cand, (rows * grid.size + best)[better])
            score = np.where(better, j[rows, best], score)
            stages.append(name)
            scores.append(score.copy())
        if "reset" in moves:  # stage 3: sparse resets
            sizes = np.asarray(RESET_FRACTIONS[1:])
            for _ in range(MAX_RESETS):
                states, prefix = runner.snapshots(sched, RESET_EVERY)
                best_j, best_at = score.copy(), np.full((b, 2), -1)
                for q in sorted(states):
                    trials = np.repeat(rows, sizes.size)
                    cand = _candidates(sched, trials)
                    cand.reset[:, q] = np.maximum(cand.reset[:, q], np.tile(sizes, b))
                    bound = best_j[trials] ** 2 - prefix[q][trials]  # S to beat after q
                    s = prefix[q][trials] + runner.run(trials, cand, q, states[q], bound)
                    j = runner.scorer.score(s).reshape(b, sizes.size)
                    k = np.argmin(j, axis=1)
                    win = j[rows, k] < best_j
                    best_j = np.where(win, j[rows, k], best_j)
                    best_at[win] = np.column_stack([np.full(b, q), k])[win]
                won = best_at[:, 0] >= 0
                for i in np.flatnonzero(won):
                    q, k = best_at[i]
                    sched.reset[i, q] = max(sched.reset[i, q], sizes[k])
                score = np.where(won, best_j, score)
                stages.append("reset")
                scores.append(score.copy())
                if not won.any():
                    break
        out = run_moves(cfg, data, sched)
        out.logs["hindsight_moves_scores"] = np.stack(scores, axis=1)
        out.logs["hindsight_moves_stages"] = np.array(stages)
        mean = np.mean(scores, axis=1)
        means = " → ".join(f"{m:.4g} ({s})" for s, m in zip(stages, mean, strict=True))
        n_resets = np.sum(sched.reset > 0.0) / b
        notes["hindsight-moves"] = (
            f"per-trial best schedule of the moves {'+'.join(moves)} with the truth known; mean "
            f"{cfg.adaptive.tuned.metric} {means}; {n_resets:.2g} resets per trial; "
            f"{runner.trial_epochs / b:.3g} trial-epochs per trial besides the κ stage (a "
            "yardstick, not a flight method)"
        )
        out.notes.update(notes)
        return out


def hindsight_moves_method(controls: str) -> HindsightMoves:
    """Method factory of ``hindsight-moves:CONTROLS`` (``ValueError`` for an unknown
    control)."""
    controlled_moves(controls)
    return HindsightMoves(controls)
