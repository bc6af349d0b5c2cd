r"""The gyro ``hindsight`` yardstick: the best κ schedule of one episode with its truth known
(docs/redundant_gyros.md, "Hindsight").

An episode is one run of the calibration UKF of ``qkf/RedundantGyroCalibration-v0/-v1``
(:func:`episode`: the same readings, truth and steps as the environment's ``reset(seed=…)``).
A schedule holds one κ of the action set ``{κ_a}`` (``environment.actions``) per decision
period of ``P`` epochs (``environment.period_s``). Its criterion is the settled mean square of
the calibrated states in units of their prior sd,

    J(u) = 1 / (4 N_s) Σ_{k settled} Σ_{i ∈ [b, λ, δ_u, δ_v]} ((x̂_{k,i} − x_{k,i}) / σ_{0,i})²,

dimensionless, over the ``N_s`` epochs from ``settled_s`` (time since the calibration
started, s) to the end; a filter that fails scores ``inf``. The prior sds weigh the four states
as the environment's ``oracle`` reward and its rendering do.

Search (as :mod:`qkf.transfer_alignment.methods.schedule_search`, written here for the gyro
UKF): start from the best constant schedule of the episode, then coordinate descent over
blocks of periods, coarse to fine (``blocks``): a sweep visits the blocks in time order and
tries every action held over the block with the incumbent everywhere else, keeping it only if
strictly better — so the result is never worse than the episode's best constant κ, nor than
any constant. The incumbent filter is carried from block to block, so a candidate runs from
its block's start only, and the criterion's sum before it is the incumbent's.

The filter is the compiled UKF of :mod:`qkf.redundant_gyros.ukf_compiled` (the environments'
too). Its estimates agree with filterpy's to rounding (tested), at about a thousandth of the
cost, which is what makes the search affordable (about 4·10⁶ filter steps
per 600-s episode).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.episodes import EpisodeInputs, EpisodeSampler
from qkf.redundant_gyros.ukf import DIM, UkfSetup
from qkf.redundant_gyros.ukf_compiled import CompiledSetup, run_span, step_work, ukf_step

SETTLED_S = 100.0
"""Default start of the judged window, s after the calibration starts: the UKF has converged
from its prior by then (about 400 steps in the paper), and the preset's onsets come later."""
BLOCKS = (16, 8, 4, 2, 1)
"""Default block lengths of the search, in decision periods, coarse to fine."""


def env_draw(seed: int) -> int:
    """The simulation seed an environment's ``reset(seed=seed)`` draws (Gymnasium seeds
    ``np_random`` as ``default_rng(seed)``)."""
    return int(np.random.default_rng(seed).integers(2**63 - 1))


@dataclass(frozen=True)
class Episode:
    """One calibration episode with what the search needs (internal units)."""

    inputs: EpisodeInputs
    setup: UkfSetup
    kappas: np.ndarray  # (A,) the action set
    period: int  # epochs per decision period
    settled_from: int  # first judged epoch (index into the calibrated epochs)
    seed: int  # the environment seed it reproduces

    @property
    def n_epochs(self) -> int:
        return int(self.inputs.z.size)

    @property
    def n_periods(self) -> int:
        return -(-self.n_epochs // self.period)


def episode(cfg: GyrosConfig, seed: int, settled_s: float = SETTLED_S) -> Episode:
    """The episode of ``env.reset(seed=seed)`` of a gyro environment on ``cfg``."""
    sampler = EpisodeSampler(cfg)
    setup = sampler.setup
    inputs = sampler.draw(env_draw(seed))
    period = max(1, round(cfg.environment.period_s / cfg.scenario.dt_s))
    settled = int(np.searchsorted(np.cumsum(inputs.dt) - inputs.dt[0], settled_s - 1e-9))
    if settled >= inputs.z.size:
        raise ValueError(f"settled_s = {settled_s:g} s leaves no judged epoch in the episode")
    kappas = np.asarray(cfg.environment.actions.values(), dtype=float)
    return Episode(inputs, setup, kappas, period, settled, seed)


# --- the compiled filter: qkf.redundant_gyros.ukf_compiled ----------------------------------


class CompiledUKF:
    """The compiled calibration UKF of one episode (module docstring)."""

    def __init__(self, ep: Episode) -> None:
        self.ep = ep
        compiled = CompiledSetup.of(ep.setup)
        self.weights = compiled.weights
        self.geometry = compiled.geometry
        self.inv_sd = 1.0 / ep.setup.p0_sd
        self.norm = float((ep.n_epochs - ep.settled_from) * DIM)

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        s = self.ep.setup
        return s.x0.copy(), np.diag(s.p0_sd**2)

    def run(self, x: np.ndarray, p: np.ndarray, kappa: np.ndarray, k0: int, k1: int) -> float:
        """Advance ``(x, p)`` in place over ``[k0, k1)`` with κ per epoch ``kappa`` (k1 − k0,);
        the settled sum of squared normalised errors there (NaN: the filter failed)."""
        i = self.ep.inputs
        return float(
            run_span(
                x,
                p,
                i.z,
                i.rate,
                i.dt,
                kappa,
                i.truth,
                self.inv_sd,
                k0,
                k1,
                self.ep.settled_from,
                self.geometry,
                self.weights,
            )
        )

    def estimates(self, kappa: np.ndarray) -> np.ndarray:
        """Posterior estimates (K, 4) over the episode with κ per epoch (NaN after a failure)."""
        i = self.ep.inputs
        x, p = self.prior()
        out = np.full((i.z.size, DIM), np.nan)
        work = step_work()
        for k in range(i.z.size):
            _, s = ukf_step(
                x, p, float(i.z[k]), i.rate[k], float(i.dt[k]), float(kappa[k]),
                self.geometry, self.weights, work,
            )  # fmt: skip
            if np.isnan(s):
                break
            out[k] = x
        return out

    def score(self, total: float) -> float:
        """``J`` from a settled sum (``inf`` if not finite)."""
        j = total / self.norm
        return j if np.isfinite(j) else float(np.inf)


# --- the search -----------------------------------------------------------------------------


@dataclass(frozen=True)
class HindsightResult:
    """The best schedule found for one episode.

    ``choice`` (T,): action index per period; ``score``: its ``J``; ``constant_scores`` (A,):
    ``J`` of every constant κ of the action set; ``stages``/``stage_scores``: ``J`` after the
    start and each sweep; ``runs``: rollouts; ``filter_steps``: epochs filtered in all;
    ``seconds``: wall time.
    """

    choice: np.ndarray
    score: float
    constant_scores: np.ndarray
    stages: tuple[str, ...]
    stage_scores: tuple[float, ...]
    runs: int
    filter_steps: int
    seconds: float

    def kappa(self, kappas: np.ndarray, period: int, n_epochs: int) -> np.ndarray:
        """κ per epoch (n_epochs,) of the schedule."""
        return np.asarray(kappas[np.repeat(self.choice, period)[:n_epochs]])


def constant_scores(ep: Episode) -> np.ndarray:
    """``J`` of each constant κ of the action set over the episode (A,)."""
    ukf = CompiledUKF(ep)
    out = np.empty(ep.kappas.size)
    for a, kap in enumerate(ep.kappas):
        x, p = ukf.prior()
        out[a] = ukf.score(ukf.run(x, p, np.full(ep.n_epochs, kap), 0, ep.n_epochs))
    return out


def search(ep: Episode, blocks: Sequence[int] = BLOCKS, passes: int = 1) -> HindsightResult:
    """Coordinate descent for the best schedule of ``ep`` (module docstring): ``blocks``
    lengths in periods, coarse to fine, ``passes`` sweeps at each length (a pass that changes
    nothing ends that length)."""
    tic = time.perf_counter()
    ukf = CompiledUKF(ep)
    n, per, t_n, a_n = ep.n_epochs, ep.period, ep.n_periods, ep.kappas.size
    const = constant_scores(ep)
    runs, steps = a_n, a_n * n
    choice = np.full(t_n, int(np.argmin(const)))
    score = float(const[choice[0]])
    stages, stage_scores = ["start"], [score]
    for length in blocks:
        for rep in range(passes):
            changed = False
            x, p = ukf.prior()
            prefix = 0.0
            for p0 in range(0, t_n, length):
                p1 = min(t_n, p0 + length)
                k0, k1 = p0 * per, min(n, p1 * per)
                block = choice[p0:p1]
                same = bool(np.all(block == block[0]))
                best_a, best_s = -1, score
                for act in range(a_n):
                    if same and act == block[0]:
                        continue  # the incumbent: its score is known
                    cand = choice.copy()
                    cand[p0:p1] = act
                    kap = ep.kappas[np.repeat(cand, per)[k0:n]]
                    total = prefix + ukf.run(x.copy(), p.copy(), kap, k0, n)
                    runs += 1
                    steps += n - k0
                    s = ukf.score(total)
                    if s < best_s:
                        best_a, best_s = act, s
                if best_a >= 0:
                    choice[p0:p1] = best_a
                    score = best_s
                    changed = True
                kap = ep.kappas[np.repeat(choice, per)[k0:k1]]
                prefix += ukf.run(x, p, kap, k0, k1)
                steps += k1 - k0
            stages.append(f"{length} periods #{rep + 1}")
            stage_scores.append(score)
            if not changed:
                break
    return HindsightResult(
        choice=choice,
        score=score,
        constant_scores=const,
        stages=tuple(stages),
        stage_scores=tuple(stage_scores),
        runs=runs,
        filter_steps=steps,
        seconds=time.perf_counter() - tic,
    )


def switch_period(ep: Episode) -> int:
    """The first period that starts after the drawn onset (a policy that reads the evidence of
    one period can switch there); ``n_periods`` if the episode has no onset inside it."""
    i = ep.inputs
    if i.onset_s is None:
        return ep.n_periods
    since = np.cumsum(i.dt) - i.dt[0]  # time since the calibration started, per epoch
    k = int(np.searchsorted(since, i.onset_s - i.t0_s - 1e-9))
    return min(ep.n_periods, k // ep.period + 1)


def two_level_scores(ep: Episode) -> np.ndarray:
    """``J`` (A, A) of the onset-informed schedules: κ_a before :func:`switch_period`, κ_c from
    it on (row a, column c). They know the onset time and nothing of the noise: the
    adaptation a policy that detects the onset within a period could reach."""
    ukf = CompiledUKF(ep)
    a_n, n = ep.kappas.size, ep.n_epochs
    k_sw = min(n, switch_period(ep) * ep.period)
    out = np.empty((a_n, a_n))
    for a in range(a_n):
        x, p = ukf.prior()
        head = ukf.run(x, p, np.full(k_sw, ep.kappas[a]), 0, k_sw)
        for c in range(a_n):
            tail = ukf.run(x.copy(), p.copy(), np.full(n - k_sw, ep.kappas[c]), k_sw, n)
            out[a, c] = ukf.score(head + tail)
    return out


def best_constant(scores: np.ndarray) -> int:
    """The action index with the best mean ``J`` over episodes, from ``scores`` (episodes, A)
    (a diverged episode, ``inf``, rules its κ out)."""
    return int(np.argmin(np.mean(scores, axis=0)))


__all__ = [
    "BLOCKS",
    "SETTLED_S",
    "CompiledUKF",
    "Episode",
    "HindsightResult",
    "best_constant",
    "constant_scores",
    "env_draw",
    "episode",
    "search",
    "switch_period",
    "two_level_scores",
]
