r"""Controls of ``qkf/TransferAlignment-v4``: which of the filter's moves the agent makes
(:mod:`qkf.transfer_alignment.moves`), chosen by the environment keyword ``controls``
(docs/environment.md, "Controls").

``controls`` names one control or several joined with ``+`` (``"kappa+reset+r_scale"``). Each
control adds action dimensions, in this order:

===========  ======================  ==========================================================
Control      Dimensions              Values (discrete: an index; continuous: [−1, 1] → range)
===========  ======================  ==========================================================
``kappa``    κ                       the config's action set (``adaptive.actions``), log scale
``blocks``   q_att, q_bias, κ        :data:`~qkf.transfer_alignment.moves.BLOCK_SCALES` (0.1 …
                                     10) for attitude and bias, the action set for calibration
``reset``    f                       :data:`~qkf.transfer_alignment.moves.RESET_FRACTIONS` (0,
                                     1 … 30 % of the calibration prior σ); continuous: f =
                                     f_max · max(0, u)
``r_scale``  r                       :data:`~qkf.transfer_alignment.moves.R_SCALES` (½ … 4 ×
                                     the assumed ADS attitude σ), log scale
``r_step``   Δr                      one step down the r grid, keep, one step up (persistent:
                                     the episode's r moves; continuous: thirds of [−1, 1])
``kappa_step`` Δκ                    the same for κ (on a residual: for its factor)
===========  ======================  ==========================================================

``blocks`` holds the calibration κ, so it does not combine with ``kappa``. Action space:
``Discrete(A)`` for one dimension (``controls="kappa"`` is v3's), ``MultiDiscrete`` for more;
``Box(−1, 1, (D,))`` with ``action_type="continuous"``. A dimension not controlled stays
nominal (κ: the action set's nominal value).

**Residual controls** (``base="nis-rule"`` or ``base="glr"``): a classical rule decides every
period as the method of that name would (the config's ``adaptive.nis_rule`` or
``adaptive.glr`` settings), and the agent's action corrects it. The κ dimension becomes a
factor on the rule's κ (:data:`RESIDUAL_FACTORS`, index 2 = × 1); the reset dimension
(:data:`RESIDUAL_RESETS`) vetoes the rule's reset (index 0), keeps it (index 1) or adds one to
it (in quadrature); the other dimensions are absolute as above. The all-nominal action
(:meth:`ControlMap.neutral`) therefore runs the rule itself: with ``base="nis-rule"`` the
``nis-rule`` method, bit for bit; with ``base="glr"`` GLR decided per period (re-opening at the
next period's start, not the next epoch).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from gymnasium import spaces

from qkf.core.registry import Registry
from qkf.transfer_alignment.adaptive import GlrConfig, NisRuleConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.alarm_burst import nis_per_row
from qkf.transfer_alignment.methods.base import settings_of
from qkf.transfer_alignment.methods.glr import GlrPeriodDecision, run_glr
from qkf.transfer_alignment.methods.nis_rule import NisRuleDecision, run_nis_rule
from qkf.transfer_alignment.moves import (
    BLOCK_SCALES,
    R_SCALES,
    RESET_FRACTIONS,
    Moves,
    grid_position,
)
from qkf.transfer_alignment.params import FilterParams

RESIDUAL_FACTORS = (0.1, 10.0**-0.5, 1.0, 10.0**0.5, 10.0)
"""The residual κ dimension: factors on the base rule's κ (index 2: the rule's own)."""
VETO = -1.0
RESIDUAL_RESETS = (VETO, *RESET_FRACTIONS)
"""The residual reset dimension: index 0 vetoes the rule's reset (none this period), index 1
keeps the rule's decision, the others add a reset of that size to it (in quadrature)."""

CONTROL_DIMENSIONS = {
    "kappa": ("kappa",),
    "blocks": ("q_att", "q_bias", "kappa"),
    "reset": ("reset",),
    "r_scale": ("r_scale",),
    "r_step": ("r_step",),
    "kappa_step": ("kappa_step",),
}
"""The dimensions each control adds, in action order."""
DIMENSION_ORDER = ("kappa", "kappa_step", "q_att", "q_bias", "reset", "r_scale", "r_step")
R_STEPS = (-1.0, 0.0, 1.0)
"""``r_step`` and ``kappa_step``: one step down their grid, none, one step up (index 1:
keep)."""
STEPPED = {"r_step": "r_scale", "kappa_step": "kappa"}
"""The persistent controls and the move each one steps."""
"""Action dimensions appear in this order whatever the order of ``controls``."""


@dataclass(frozen=True)
class Dimension:
    """One action dimension: its grid, the index of its neutral value, and whether the
    continuous action maps to it linearly in log (else: linearly, clipped at 0)."""

    name: str
    grid: np.ndarray
    neutral: int
    log: bool = True


def parse_controls(controls: str) -> tuple[str, ...]:
    """The dimensions of a ``controls`` string, in action order; ``ValueError`` naming the
    known controls for an unknown one, and for ``kappa`` with ``blocks``."""
    names = [c.strip() for c in str(controls).split("+")]
    unknown = [c for c in names if c not in CONTROL_DIMENSIONS]
    if unknown or not names:
        raise ValueError(
            f"unknown control {unknown[0] if unknown else controls!r}; known: "
            f"{', '.join(CONTROL_DIMENSIONS)} (joined with '+')"
        )
    if "kappa" in names and "blocks" in names:
        raise ValueError("controls: 'blocks' sets the calibration κ already; drop 'kappa'")
    if "r_scale" in names and "r_step" in names:
        raise ValueError("controls: 'r_step' moves r_scale already; drop 'r_scale'")
    if "kappa_step" in names and ("kappa" in names or "blocks" in names):
        raise ValueError("controls: 'kappa_step' moves κ already; drop 'kappa' and 'blocks'")
    if len(set(names)) != len(names):
        raise ValueError(f"controls: {controls!r} names a control twice")
    dims = {d for c in names for d in CONTROL_DIMENSIONS[c]}
    return tuple(d for d in DIMENSION_ORDER if d in dims)


class BaseRule(Protocol):
    """A classical rule deciding once per period for N runs (the residual's base)."""

    def reset(self, rows: np.ndarray) -> None: ...

    def start(self) -> Moves:
        """The decision of every run's first period."""
        ...

    def __call__(self, nis: np.ndarray, valid: np.ndarray, t_end: np.ndarray) -> Moves:
        """The next period's decision from this period's per-epoch NIS (N, P) (``valid``
        epochs only) and the time at its end (N,), s."""
        ...


class NisRuleBase:
    """``base="nis-rule"``: :class:`~qkf.transfer_alignment.methods.nis_rule.NisRuleDecision`
    with the config's ``adaptive.nis_rule`` (its ``period_s`` must be the environment's)."""

    def __init__(self, cfg: Config, n: int, period_s: float) -> None:
        nr = settings_of(run_nis_rule, cfg, NisRuleConfig)
        if abs(nr.period_s - period_s) > 1e-9:
            raise ValueError(
                f"base nis-rule decides every adaptive.nis_rule.period_s = {nr.period_s:g} s, "
                f"the environment every {period_s:g} s: make them equal"
            )
        self.n, self.kappa0 = n, nr.kappa_base
        self.rule = NisRuleDecision(nr, n)
        self.n_meas = FilterParams.from_config(cfg).n_meas
        self.dt = cfg.scenario.dt_s

    def reset(self, rows: np.ndarray) -> None:
        self.rule.reset(rows)

    def start(self) -> Moves:
        return Moves.nominal(self.n, self.kappa0)

    def __call__(self, nis: np.ndarray, valid: np.ndarray, t_end: np.ndarray) -> Moves:
        x = nis_per_row(np.where(valid, nis, np.nan), self.n_meas)
        steps = np.maximum(valid.sum(axis=1), 1)
        return Moves.nominal(self.n, self.rule(x, steps * self.dt))


class GlrBase:
    """``base="glr"``: :class:`~qkf.transfer_alignment.methods.glr.GlrPeriodDecision` with
    the config's ``adaptive.glr``: κ constant, a reset of ``reset_ppm`` on an alarm."""

    def __init__(self, cfg: Config, n: int, period_s: float) -> None:
        params = FilterParams.from_config(cfg)
        glr = settings_of(run_glr, cfg, GlrConfig)
        self.n, self.kappa0 = n, glr.kappa
        self.rule = GlrPeriodDecision(glr, n, params.n_meas)
        # reset_ppm as a fraction of the calibration prior σ (one σ for the nine terms)
        self.fraction = glr.reset_ppm * 1e-6 / float(params.p0_sigma[6])

    def reset(self, rows: np.ndarray) -> None:
        self.rule.reset(rows)

    def start(self) -> Moves:
        return Moves.nominal(self.n, self.kappa0)

    def __call__(self, nis: np.ndarray, valid: np.ndarray, t_end: np.ndarray) -> Moves:
        reopen = self.rule(np.where(valid, nis, np.nan), t_end)
        return dataclasses.replace(
            Moves.nominal(self.n, self.kappa0), reset=np.where(reopen, self.fraction, 0.0)
        )


def tuned_on_mixture(name: str, section: str, rule: Callable[[Config, int, float], BaseRule]):  # type: ignore[no-untyped-def]
    """The base ``rule`` with the settings the ``NAME-mixed`` baseline runs with: ``name``
    (``glr-tuned``, ``nis-rule-tuned``) tuned on the training mixture at the config's step
    and duration (from the tuning cache when it has them; else tuned now, minutes)."""

    def factory(cfg: Config, n: int, period_s: float) -> BaseRule:
        from qkf.transfer_alignment.methods.on_mixture import mixture_config
        from qkf.transfer_alignment.methods.tuned import TUNED_METHODS, with_section

        tuned = TUNED_METHODS[name].prepare(mixture_config(cfg))
        return rule(with_section(cfg, section, dict(tuned.settings)), n, period_s)

    return factory


BASES: Registry[Callable[[Config, int, float], BaseRule]] = Registry("base", group=None)
"""Residual bases by name (``base=`` of v4): ``factory(cfg, n, period_s)``. The ``-mixed``
ones run the rule with the settings of the baseline of that name (tuned on the training
mixture): the best classical level on the mixture to start from."""
BASES.register("nis-rule", NisRuleBase)
BASES.register("glr", GlrBase)
BASES.register("glr-tuned-mixed", tuned_on_mixture("glr-tuned", "glr", GlrBase))
BASES.register("nis-rule-tuned-mixed", tuned_on_mixture("nis-rule-tuned", "nis_rule", NisRuleBase))


class ControlMap:
    """Actions → :class:`~qkf.transfer_alignment.moves.Moves` for N runs (module docstring)."""

    def __init__(
        self,
        cfg: Config,
        controls: str,
        action_type: str,
        base: str | None = None,
        n: int = 1,
        period_s: float = 10.0,
    ) -> None:
        if action_type not in ("discrete", "continuous"):
            raise ValueError(f"action_type must be 'discrete' or 'continuous', not {action_type!r}")
        self.controls = controls
        self.action_type = action_type
        self.names = parse_controls(controls)
        kappas = np.asarray(cfg.adaptive.actions.values(), dtype=float)
        self.kappas = kappas
        self.kappa_nominal = float(kappas[cfg.adaptive.actions.nominal_index()])
        self.base_name = base
        self.base: BaseRule | None = None
        if base is not None:
            if base not in BASES:
                raise ValueError(f"unknown base {base!r}; known: {', '.join(BASES.names())}")
            self.base = BASES[base](cfg, n, period_s)
        kappa_dim = (
            Dimension("kappa", np.asarray(RESIDUAL_FACTORS), RESIDUAL_FACTORS.index(1.0))
            if base is not None
            else Dimension("kappa", kappas, cfg.adaptive.actions.nominal_index())
        )
        grids = {
            "kappa": kappa_dim,
            "q_att": Dimension("q_att", np.asarray(BLOCK_SCALES), BLOCK_SCALES.index(1.0)),
            "q_bias": Dimension("q_bias", np.asarray(BLOCK_SCALES), BLOCK_SCALES.index(1.0)),
            "reset": (
                Dimension("reset", np.asarray(RESIDUAL_RESETS), 1, log=False)
                if base is not None
                else Dimension("reset", np.asarray(RESET_FRACTIONS), 0, log=False)
            ),
            "r_scale": Dimension("r_scale", np.asarray(R_SCALES), R_SCALES.index(1.0)),
            "r_step": Dimension("r_step", np.asarray(R_STEPS), 1, log=False),
            "kappa_step": Dimension("kappa_step", np.asarray(R_STEPS), 1, log=False),
        }
        # r_step, kappa_step: each episode's level on the r_scale (κ) grid, moved by the actions
        self.r_nominal = R_SCALES.index(1.0)
        self.r_level = np.full(n, self.r_nominal, dtype=np.int64)
        self.k_grid, self.k_nominal = kappa_dim.grid, kappa_dim.neutral
        self.k_level = np.full(n, self.k_nominal, dtype=np.int64)
        self.dims = tuple(grids[d] for d in self.names)
        sizes = [d.grid.size for d in self.dims]
        self.space: spaces.Space[Any]
        if action_type == "continuous":
            self.space = spaces.Box(-1.0, 1.0, shape=(len(self.dims),), dtype=np.float32)
        elif len(sizes) == 1:
            self.space = spaces.Discrete(sizes[0])
        else:
            self.space = spaces.MultiDiscrete(sizes)

    @property
    def size(self) -> int:
        """Action dimensions."""
        return len(self.dims)

    def neutral(self) -> np.ndarray:
        """The discrete action of nominal moves (the base rule itself, for a residual)."""
        return np.array([d.neutral for d in self.dims], dtype=np.int64)

    def values(self, actions: Any, n: int) -> np.ndarray:
        """The grid values of N actions (N, D); ``ValueError`` for an invalid action."""
        a = np.asarray(actions)
        if self.action_type == "discrete":
            if not (np.issubdtype(a.dtype, np.integer) or _integral(a)):
                raise ValueError(f"discrete actions must be integer indices, got {actions!r}")
            idx = a.astype(np.int64).reshape(n, self.size)
            out = np.empty(idx.shape)
            for j, d in enumerate(self.dims):
                if np.any((idx[:, j] < 0) | (idx[:, j] >= d.grid.size)):
                    raise ValueError(f"{d.name} action outside 0..{d.grid.size - 1}: {actions!r}")
                out[:, j] = d.grid[idx[:, j]]
            return out
        u = np.asarray(a, dtype=float).reshape(n, self.size)
        if not np.all(np.isfinite(u)) or np.any(np.abs(u) > 1.0 + 1e-6):
            raise ValueError(f"continuous actions must be finite, in [-1, 1], got {actions!r}")
        u = np.clip(u, -1.0, 1.0)
        out = np.empty(u.shape)
        for j, d in enumerate(self.dims):
            if d.log:
                lo, hi = np.log(d.grid[0]), np.log(d.grid[-1])
                out[:, j] = np.exp(lo + (u[:, j] + 1.0) / 2.0 * (hi - lo))
            elif d.name in STEPPED:  # thirds: down, keep, up
                out[:, j] = np.where(u[:, j] < -1 / 3, -1.0, np.where(u[:, j] > 1 / 3, 1.0, 0.0))
            else:  # reset: none below 0, then linear up to the largest size
                out[:, j] = d.grid[-1] * np.maximum(0.0, u[:, j])
                if d.grid[0] == VETO:  # a residual's: the lowest quarter vetoes the rule's
                    out[:, j] = np.where(u[:, j] < -0.5, VETO, out[:, j])
        return out

    def moves(self, actions: Any, n: int, base: Moves | None = None) -> Moves:
        """The moves of N actions, on top of the base rule's decision ``base`` (residual)."""
        v = dict(zip(self.names, self.values(actions, n).T, strict=True))
        if "kappa_step" in v:  # persistent: the episode's κ level moves by the step
            top = self.k_grid.size - 1
            self.k_level = np.clip(self.k_level + v["kappa_step"].astype(np.int64), 0, top)
            v["kappa"] = self.k_grid[self.k_level]
        if self.base is not None:
            assert base is not None
            kappa = base.kappa * v.get("kappa", 1.0)
            add = v.get("reset", np.zeros(n))
            # in quadrature on top of the rule's reset, or none at all (the veto)
            reset = np.where(add == VETO, 0.0, np.sqrt(base.reset**2 + np.maximum(add, 0.0) ** 2))
        else:
            kappa = v.get("kappa", np.full(n, self.kappa_nominal))
            reset = v.get("reset", np.zeros(n))
        ones = np.ones(n)
        r_scale = v.get("r_scale", ones)
        if "r_step" in v:  # persistent: the episode's level moves by the step
            self.r_level = np.clip(
                self.r_level + v["r_step"].astype(np.int64), 0, len(R_SCALES) - 1
            )
            r_scale = np.asarray(R_SCALES)[self.r_level]
        return Moves(
            kappa=np.broadcast_to(kappa, (n,)).astype(float),
            q_att=np.broadcast_to(v.get("q_att", ones), (n,)).astype(float),
            q_bias=np.broadcast_to(v.get("q_bias", ones), (n,)).astype(float),
            r_scale=np.broadcast_to(r_scale, (n,)).astype(float),
            reset=np.broadcast_to(reset, (n,)).astype(float),
        )

    def restart(self, rows: np.ndarray) -> None:
        """Episodes ``rows`` start anew: their ``r_step`` and ``kappa_step`` levels back to
        the nominal."""
        self.r_level[rows] = self.r_nominal
        self.k_level[rows] = self.k_nominal

    def kappa_position(self, kappa: np.ndarray) -> np.ndarray:
        """Where κ lies on the action set's log range, 0 … 1 (the observation's κ entry)."""
        return grid_position(kappa, self.kappas)

    def actions_of(self, moves: Moves, base: Moves | None = None) -> np.ndarray:
        """The discrete actions (N, D) nearest to ``moves``, for datasets and imitation of
        decisions made outside the environment. A residual's are relative to the base rule's
        decision ``base``: κ as a factor on the rule's, the reset as what is added to the
        rule's in quadrature."""
        kappa, reset = moves.kappa, moves.reset
        if self.base is not None:
            assert base is not None
            kappa = moves.kappa / base.kappa
            vetoed = (moves.reset == 0.0) & (base.reset > 0.0)
            added = np.sqrt(np.maximum(0.0, moves.reset**2 - base.reset**2))
            reset = np.where(vetoed, VETO, added)
        # r_step: the step from the episode's level toward the level of the moves' r
        want = np.argmin(np.abs(np.log(moves.r_scale)[:, None] - np.log(R_SCALES)[None]), axis=1)
        by_name = {
            "kappa": kappa, "q_att": moves.q_att, "q_bias": moves.q_bias,
            "reset": reset, "r_scale": moves.r_scale,
            "r_step": np.sign(want - self.r_level).astype(float),
            "kappa_step": np.sign(
                np.argmin(np.abs(np.log(kappa)[:, None] - np.log(self.k_grid)[None]), axis=1)
                - self.k_level
            ).astype(float),
        }  # fmt: skip
        cols = []
        for d in self.dims:
            v = np.asarray(by_name[d.name], dtype=float)
            if d.log:
                cols.append(np.argmin(np.abs(np.log(v)[:, None] - np.log(d.grid)[None]), axis=1))
            else:
                cols.append(np.argmin(np.abs(v[:, None] - d.grid[None]), axis=1))
        return np.stack(cols, axis=1).astype(np.int64)


def _integral(a: np.ndarray) -> bool:
    return bool(
        np.issubdtype(a.dtype, np.floating) and np.all(np.isfinite(a)) and np.all(a == np.round(a))
    )
