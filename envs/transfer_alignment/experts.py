"""Experts of ``qkf/TransferAlignment-v4`` (``expert=``): who to imitate, as actions of the
environment's own controls, for behavioural cloning and DAgger (:mod:`agents.imitation`) and
datasets (docs/environment.md, "Experts").

An expert sees the environment, not only the observation, and answers for every episode's
next period:

==============  ===============================================================================
Expert          Its action
==============  ===============================================================================
``neutral``     the nominal moves (with a residual's ``base=``: the base rule itself)
``nis-rule``    the ``nis-rule`` method's decision, run alongside on the same episode
``glr``         GLR decided per period (``base="glr"``'s rule), run alongside
==============  ===============================================================================

A rule expert keeps its own state (alarms, CUSUM) from the episode's NIS, whatever the agent
does; its decision is mapped to the nearest discrete action (:meth:`ControlMap.actions_of`,
relative to the base under residual controls).
"""

from __future__ import annotations

import numpy as np

from envs.transfer_alignment.controls import BASES, BaseRule, ControlMap
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.moves import Moves

EXPERTS = ("neutral", *BASES.names())
"""The names ``expert=`` accepts."""


class RuleExpert:
    """A classical rule run alongside the agent (or the neutral action when ``rule`` is None)."""

    def __init__(self, controls: ControlMap, rule: BaseRule | None, n: int) -> None:
        if controls.action_type != "discrete":
            raise ValueError("experts answer with discrete actions: use action_type='discrete'")
        self.controls, self.rule, self.n = controls, rule, n
        self.moves = None if rule is None else rule.start()

    def reset(self, rows: np.ndarray) -> None:
        if self.rule is None or self.moves is None:
            return
        self.rule.reset(rows)
        self.moves.put(rows, self.rule.start())

    def update(self, out: object) -> None:
        """Advance the rule by the period just run (a :class:`StepOutput`)."""
        if self.rule is not None:
            self.moves = self.rule(out.nis, out.valid, out.t_s)  # type: ignore[attr-defined]

    def actions(self, base: Moves | None) -> np.ndarray:
        """(N, D) discrete actions."""
        if self.moves is None:
            return np.tile(self.controls.neutral(), (self.n, 1))
        return self.controls.actions_of(self.moves, base)


def make_expert(
    name: str | None, controls: ControlMap | None, cfg: Config, n: int, period_s: float
) -> RuleExpert | None:
    """The expert ``name`` for N episodes (None: none); ``ValueError`` for an unknown name or
    an environment without controls."""
    if name is None:
        return None
    if controls is None:
        raise ValueError("expert= needs controls= (qkf/TransferAlignment-v4)")
    if name not in EXPERTS:
        raise ValueError(f"unknown expert {name!r}; known: {', '.join(EXPERTS)}")
    rule = None if name == "neutral" else BASES[name](cfg, n, period_s)
    return RuleExpert(controls, rule, n)
