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

The filter is a compiled copy of :class:`~qkf.redundant_gyros.ukf.CalibrationUKF` (filterpy's
UKF with Merwe sigma points and an identity process model): predict ``P⁻ = P + κ Δt diag(q²)``,
sigma points of ``(x, P⁻)``, ``h`` and ``R(x)`` as :mod:`~qkf.redundant_gyros.ukf`, update
``P − K S Kᵀ``, symmetrised. Its estimates agree with filterpy's to rounding (tested), at about
a hundredth of the cost, which is what makes the search affordable (about 4·10⁶ filter steps
per 600-s episode).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np

import qkf.core.jit  # noqa: F401  (binds compiled callees locally: docs/performance.md)
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import EpisodeInputs, episode_inputs, fault_target, setup_for
from qkf.redundant_gyros.scenario import epochs
from qkf.redundant_gyros.ukf import DIM, UkfSetup

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
    unit = build_unit(cfg)
    sc = cfg.scenario
    t = epochs(sc.duration_s, sc.dt_s)
    target = fault_target(cfg, unit, t)
    setup = setup_for(cfg, unit, target)
    inputs = episode_inputs(cfg, unit, setup, target, t, env_draw(seed))
    period = max(1, round(cfg.environment.period_s / sc.dt_s))
    settled = int(np.searchsorted(np.cumsum(inputs.dt) - inputs.dt[0], settled_s - 1e-9))
    if settled >= inputs.z.size:
        raise ValueError(f"settled_s = {settled_s:g} s leaves no judged epoch in the episode")
    kappas = np.asarray(cfg.environment.actions.values(), dtype=float)
    return Episode(inputs, setup, kappas, period, settled, seed)


# --- the compiled filter --------------------------------------------------------------------


@nb.njit(cache=True)
def _cholesky(a: np.ndarray, out: np.ndarray) -> bool:  # pragma: no cover - compiled
    """Lower Cholesky factor of the 4 × 4 ``a`` into ``out``; False if not positive definite."""
    n = a.shape[0]
    for j in range(n):
        s = a[j, j]
        for m in range(j):
            s -= out[j, m] * out[j, m]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        out[j, j] = d
        for i in range(j + 1, n):
            s = a[i, j]
            for m in range(j):
                s -= out[i, m] * out[j, m]
            out[i, j] = s / d
        for i in range(j):
            out[i, j] = 0.0
    return True


@nb.njit(cache=True)
def _h(
    s: np.ndarray, w: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray
) -> float:  # pragma: no cover
    """``(1 − λ) (w − δ_u u − δ_v v)ᵀ ω̂ − b`` of state ``s``, deg/s."""
    acc = 0.0
    for m in range(3):
        acc += (w[m] - s[2] * u[m] - s[3] * v[m]) * r[m]
    return (1.0 - s[1]) * acc - s[0]


@nb.njit(cache=True)
def _run(
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    rate: np.ndarray,
    dt: np.ndarray,
    kappa: np.ndarray,
    truth: np.ndarray,
    inv_sd: np.ndarray,
    k0: int,
    k1: int,
    settled_from: int,
    w: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    tinv: np.ndarray,
    tnoise: np.ndarray,
    noise: float,
    q2: np.ndarray,
    weights: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """Run the UKF (state ``x`` (4,), ``p`` (4, 4), in place) over epochs ``[k0, k1)`` with
    ``kappa[k - k0]``; return the sum of the squared normalised errors over the epochs from
    ``settled_from`` on, NaN if the filter fails (``x``, ``p`` then undefined).
    ``weights = [λ + n, Wm0, Wc0, Wi]`` of the Merwe points."""
    n = 4
    lam_n, wm0, wc0, wi = weights[0], weights[1], weights[2], weights[3]
    chol = np.zeros((n, n))
    scaled = np.zeros((n, n))
    sig = np.zeros((2 * n + 1, n))
    hs = np.zeros(2 * n + 1)
    pxz = np.zeros(n)
    gain = np.zeros(n)
    a = np.zeros(3)
    total = 0.0
    for k in range(k0, k1):
        kap = kappa[k - k0]
        for i in range(n):
            p[i, i] += kap * dt[k] * q2[i]
        for i in range(n):
            for j in range(n):
                scaled[i, j] = lam_n * p[i, j]
        if not _cholesky(scaled, chol):
            return np.nan
        for i in range(n):
            sig[0, i] = x[i]
        for c in range(n):
            for i in range(n):
                sig[1 + c, i] = x[i] + chol[i, c]
                sig[1 + n + c, i] = x[i] - chol[i, c]
        r = rate[k]
        zp = 0.0
        for j in range(2 * n + 1):
            hs[j] = _h(sig[j], w, u, v, r)
            zp += (wm0 if j == 0 else wi) * hs[j]
        # R at the predicted state: σ² + ‖a(x)ᵀ G_H⁻¹ diag(s_H)‖²
        for m in range(3):
            a[m] = (1.0 - x[1]) * (w[m] - x[2] * u[m] - x[3] * v[m])
        rr = noise * noise
        for m in range(3):
            acc = 0.0
            for l in range(3):
                acc += a[l] * tinv[l, m]
            acc *= tnoise[m]
            rr += acc * acc
        s = rr
        for i in range(n):
            pxz[i] = 0.0
        for j in range(2 * n + 1):
            wc = wc0 if j == 0 else wi
            dz = hs[j] - zp
            s += wc * dz * dz
            for i in range(n):
                pxz[i] += wc * (sig[j, i] - x[i]) * dz
        if not (s > 0.0 and np.isfinite(s)):
            return np.nan
        y = z[k] - zp
        for i in range(n):
            gain[i] = pxz[i] / s
            x[i] += gain[i] * y
        for i in range(n):
            for j in range(n):
                p[i, j] -= gain[i] * s * gain[j]
        for i in range(n):
            for j in range(i + 1, n):
                m_ij = 0.5 * (p[i, j] + p[j, i])
                p[i, j] = m_ij
                p[j, i] = m_ij
        ok = True
        for i in range(n):
            if not np.isfinite(x[i]):
                ok = False
            for j in range(n):
                if not np.isfinite(p[i, j]):
                    ok = False
        if not ok:
            return np.nan
        if k >= settled_from:
            for i in range(n):
                e = (x[i] - truth[k, i]) * inv_sd[i]
                total += e * e
    return total


@nb.njit(cache=True)
def _record(
    x: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    rate: np.ndarray,
    dt: np.ndarray,
    kappa: np.ndarray,
    w: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    tinv: np.ndarray,
    tnoise: np.ndarray,
    noise: float,
    q2: np.ndarray,
    weights: np.ndarray,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Run the whole episode step by step, writing each posterior ``x`` into ``out`` (K, 4);
    returns the epochs run before a failure (K if none)."""
    dummy_truth = np.zeros((1, 4))
    inv_sd = np.zeros(4)
    for k in range(z.size):
        tot = _run(
            x,
            p,
            z,
            rate,
            dt,
            kappa[k:],
            dummy_truth,
            inv_sd,
            k,
            k + 1,
            z.size,
            w,
            u,
            v,
            tinv,
            tnoise,
            noise,
            q2,
            weights,
        )
        if np.isnan(tot):
            return k
        out[k] = x
    return z.size


class CompiledUKF:
    """The compiled calibration UKF of one episode (module docstring)."""

    def __init__(self, ep: Episode) -> None:
        s = ep.setup
        self.ep = ep
        n = DIM
        lam = s.alpha**2 * (n + s.kappa_points) - n
        wm0 = lam / (n + lam)
        self.weights = np.array([n + lam, wm0, wm0 + 1.0 - s.alpha**2 + s.beta, 0.5 / (n + lam)])
        self.geometry = (s.w, s.u, s.v, s.triad_inv, s.triad_noise, float(s.noise), s.q_sd**2)
        self.inv_sd = 1.0 / s.p0_sd
        self.norm = float((ep.n_epochs - ep.settled_from) * n)

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        s = self.ep.setup
        return s.x0.copy(), np.diag(s.p0_sd**2)

    def run(self, x: np.ndarray, p: np.ndarray, kappa: np.ndarray, k0: int, k1: int) -> float:
        """Advance ``(x, p)`` in place over ``[k0, k1)`` with κ per epoch ``kappa`` (k1 − k0,);
        the settled sum of squared normalised errors there (NaN: the filter failed)."""
        i = self.ep.inputs
        return float(
            _run(
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
                *self.geometry,
                self.weights,
            )
        )

    def estimates(self, kappa: np.ndarray) -> np.ndarray:
        """Posterior estimates (K, 4) over the episode with κ per epoch (NaN after a failure)."""
        i = self.ep.inputs
        x, p = self.prior()
        out = np.full((i.z.size, DIM), np.nan)
        _record(x, p, i.z, i.rate, i.dt, kappa, *self.geometry, self.weights, out)
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
