"""The problem protocol: what an estimation problem package offers the experiments layer.

Each problem package (``qkf.transfer_alignment``, ``qkf.redundant_gyros``, …) exposes one
object that satisfies :class:`Problem`, and registers it by name in :data:`PROBLEMS`. The
layers above ``qkf`` (the zoo, policy evaluation, the families judging) ask the registry for a
problem by name, or by the environment id a policy was trained on (:func:`problem_of_env`),
instead of importing a problem package (docs/architecture.md, "Problems").

A problem has:

- ``load_config(source, overrides)``: a preset name or a path, with ``--set`` overrides, read
  and validated (``ConfigError`` naming the file and field);
- ``simulate(cfg, seed, trials)``: the simulated data of the trials ``trials`` of benchmark seed
  ``seed``, which every method of the problem is run on (paired comparisons);
- ``methods``: the registry of the problem's methods (:class:`~qkf.core.registry.Registry`);
- ``metric``: the judged metric (:class:`JudgedMetric`), what families and zoo tables report;
- ``families``: the scenario families (:class:`Families`): the judged ones, the control where
  nothing changes, the shift group nothing trains or tunes on, and the training mixture;
- ``env_ids``: the Gymnasium ids of its environments (registered by ``envs``, which a problem
  never imports: a test holds the two lists equal);
- ``seeds``: the benchmark-seed ranges for judging and for tuning (:class:`SeedRanges`);
- ``max_trials`` and ``check_workload(cfg, trials)``: the largest run it accepts, and the
  refusal (``ConfigError``) of a run too large for memory, before any work;
- ``check_methods(cfg, specs)``: the refusal of a method that cannot run on a family's config
  (a method object may offer ``check(cfg)``; ``policy:PATH`` does), before any work;
- ``method_labels(specs)`` and ``trial_errors(cfg, request)``: method specs (``NAME``,
  ``LABEL=NAME``, ``policy:PATH``, …) checked, then run on the same trials (a
  :class:`TrialRequest`), each giving the judged metric per trial: what
  :mod:`qkf.core.family_judging` compares. The tuned methods tune on the request's
  ``tuning_cfg``'s tuning trials: on a shift family, those of :attr:`Families.shift_tuned_on`.
  With a ``cache`` log, results are read from and stored in the results cache
  (:mod:`qkf.core.results_cache`; a stored result is the fresh one, byte for byte) and each
  lookup is counted in the log;
- ``bench`` and ``families_study``: its benchmark with ``qkf bench``'s files and its families
  study (:mod:`qkf.core.studies`), or ``None`` where it has none.

Adding a problem: write the object in the package's ``problem.py`` and register it with
``PROBLEMS.register_spec(name, "package.problem:PROBLEM")`` below, or, from another
distribution, in the entry-point group ``qkf.problems``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from qkf.core.registry import Registry
from qkf.core.results_cache import CacheLog
from qkf.core.studies import Bench, FamiliesStudy


class MethodOutputError(ValueError):
    """A method returned something that does not fit its problem's contract; the message says
    what (exit 2 at the command line: the method's input, not qkf, is at fault)."""


@dataclass(frozen=True)
class JudgedMetric:
    """The number a problem's methods and policies are judged by, per trial."""

    name: str  # its column in the problem's trial tables
    description: str  # one line: what it is, in which units
    lower_is_better: bool = True


@dataclass(frozen=True)
class Families:
    """A problem's scenario families: preset names of its configs."""

    judged: tuple[str, ...]  # what a policy is trained and judged on, in table order
    control: tuple[str, ...]  # nothing changes: a policy must do no harm there
    shift: tuple[str, ...]  # the shift group: never in a training mixture or a tuning run
    mixture: str | None = None  # the training mixture (one of ``judged``), if there is one
    shift_tuned_on: str | None = None
    """The family whose tuning trials the tuned methods tune on when judged on a shift family,
    so that none is told the shift it is judged under (what a policy trained on that family
    meets there); None: they tune on the shift family's own (a problem without that rule)."""

    def tuning_family(self, family: str) -> str:
        """The family whose tuning trials the tuned methods use when judged on ``family``."""
        return self.shift_tuned_on if family in self.shift and self.shift_tuned_on else family

    def all(self) -> tuple[str, ...]:
        """Every family once: the judged, the controls not among them, then the shift group."""
        seen = [*self.judged, *(c for c in self.control if c not in self.judged)]
        return (*seen, *(s for s in self.shift if s not in seen))


@dataclass(frozen=True)
class SeedRanges:
    """Benchmark seeds ``[low, high)`` by use, so nothing is judged on what it was tuned on."""

    judging: tuple[int, int]
    tuning: tuple[int, int]
    seed_per_trial: bool = False
    """Trial ``t`` of benchmark seed ``s`` draws from seed ``s + t`` (the gyro environments'
    episodes), so ``n`` trials use every seed of ``[s, s + n)``; else the trials of ``s`` are
    streams of ``s`` alone."""

    def judges(self, seed: int, trials: int = 1) -> bool:
        """Whether ``trials`` trials of benchmark seed ``seed`` draw only from judging seeds."""
        low, high = self.judging
        last = seed + max(trials, 1) - 1 if self.seed_per_trial else seed
        return low <= seed and last < high


@dataclass(frozen=True)
class TrialRequest:
    """What :meth:`Problem.trial_errors` runs: every method of ``specs`` on the trials
    ``0 … trials − 1`` of benchmark seed ``seed`` (the same data: paired)."""

    specs: tuple[str, ...]  # method specs: NAME, LABEL=NAME, policy:PATH, …
    trials: int
    seed: int  # benchmark seed
    tuning_cfg: Any = None
    """The config whose tuning trials the tuned methods tune on (None: the judged config's;
    see :attr:`Families.shift_tuned_on`)."""
    progress: bool = False  # a progress bar over the methods or trial chunks
    cache: CacheLog | None = None
    """Use the results cache and count each lookup here (None: compute everything)."""


@runtime_checkable
class Problem(Protocol):
    """An estimation problem, as the experiments layer uses it (see the module docstring)."""

    name: str
    description: str
    env_ids: tuple[str, ...]
    families: Families
    metric: JudgedMetric
    seeds: SeedRanges
    max_trials: int
    bench: Bench | None
    families_study: FamiliesStudy | None

    @property
    def methods(self) -> Registry[Any]:
        """The problem's methods, by name."""
        ...

    def load_config(self, source: str | Path | None, overrides: Sequence[str] = ()) -> Any:
        """The validated config of a preset name or a path, with ``--set`` overrides."""
        ...

    def simulate(self, cfg: Any, seed: int, trials: Sequence[int]) -> Any:
        """The simulated data of the trials ``trials`` of benchmark seed ``seed``."""
        ...

    def check_workload(self, cfg: Any, trials: int) -> None:
        """``ConfigError`` if ``trials`` trials of ``cfg`` are too many to run."""
        ...

    def method_labels(self, specs: Sequence[str]) -> list[str]:
        """The labels the method specs are reported under; ``ValueError`` naming a spec that
        cannot be resolved (checked before any work)."""
        ...

    def check_methods(self, cfg: Any, specs: Sequence[str]) -> None:
        """``ConfigError`` when a method cannot run on ``cfg`` (a policy of another action
        set), before any work: each resolved method's ``check(cfg)``, where it has one."""
        ...

    def trial_errors(self, cfg: Any, request: TrialRequest) -> dict[str, np.ndarray]:
        """Label → the judged metric per trial (trials,) of each method of ``request`` on
        ``cfg``'s trials."""
        ...


PROBLEMS: Registry[Problem] = Registry("problem", group="qkf.problems")
"""The problems by name; each is imported on first use."""
PROBLEMS.register_spec("transfer_alignment", "qkf.transfer_alignment.problem:PROBLEM")
PROBLEMS.register_spec("redundant_gyros", "qkf.redundant_gyros.problem:PROBLEM")


def problem_of_env(env_id: str) -> Problem:
    """The problem whose environments include ``env_id`` (``KeyError`` naming the known ids)."""
    for name in PROBLEMS:
        if env_id in PROBLEMS[name].env_ids:
            return PROBLEMS[name]
    known = [e for name in PROBLEMS for e in PROBLEMS[name].env_ids]
    raise KeyError(f"{env_id!r}: no problem has this environment; known: {', '.join(known)}")


__all__ = [
    "PROBLEMS",
    "Families",
    "JudgedMetric",
    "MethodOutputError",
    "Problem",
    "SeedRanges",
    "TrialRequest",
    "problem_of_env",
]
