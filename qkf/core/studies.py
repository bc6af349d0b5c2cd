"""The optional parts of a problem: a benchmark that writes ``qkf bench``'s files, and a families
study (docs/architecture.md, "The problem registry").

Beside the :class:`~qkf.core.problem.Problem` members every problem has (what ``qkf judge``
runs), a problem may offer

- ``bench``: a :class:`Bench`, the benchmark of its methods with the files of ``qkf bench``
  (``trials.csv``, ``summary.md``, figures): what ``qkf evaluate`` and a zoo entry's ``judge:``
  cases run;
- ``families_study``: a :class:`FamiliesStudy`, its ``qkf study families`` run over its
  families, the shift group and any policies of several training seeds (``NAME#SEED``): what a
  zoo entry's ``families:`` section runs.

``None`` where a problem has not got one (the zoo then refuses those sections for its entries,
naming ``judging:``, which every problem has). The layers above ``qkf`` reach them only through
the problem object (``PROBLEMS[name].bench``), never by importing the problem package.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Bench(Protocol):
    """A problem's benchmark with ``qkf bench``'s files."""

    def quick_baselines(self, cfg: Any, cache: bool) -> list[str]:
        """The baselines to show beside a policy without a tuning run of its own: those that
        need none, and the tuned ones whose tuning is in the results cache (``cache``: it may
        be read)."""
        ...

    def prepare(self, cfg: Any, specs: Sequence[str], trials: int, source: str) -> Any:
        """The methods ``specs`` resolved on ``cfg`` (read from ``source``, named in messages)
        and the workload of ``trials`` trials checked: ``ConfigError`` or ``ValueError`` before
        any work. What :meth:`run` takes."""
        ...

    def run(
        self, prepared: Any, seed: int, folder: Path, progress: bool = False, cache: bool = False
    ) -> None:
        """Run the prepared benchmark on the trials of benchmark seed ``seed`` and write its
        files into ``folder`` (created; the caller has checked it may be written)."""
        ...


@dataclass(frozen=True)
class StudyRun:
    """A families study: what to run, on which trials."""

    families: tuple[str, ...]  # the judged families (the shift group is always added)
    baselines: tuple[str, ...]  # the methods, replacing the study preset's own
    policies: tuple[str, ...]  # added after them: ``NAME#SEED=policy:PATH``
    seed: int  # benchmark seed
    trials: int  # per family
    sets: tuple[str, ...] = ()  # ``--set`` overrides of every family


@dataclass(frozen=True)
class StudyEvents:
    """What a running families study reports."""

    progress: bool = False  # progress bars
    on_start: Callable[[int, int, str], None] | None = None  # (i, n, family) before each family
    on_case: Callable[[str, bool], None] | None = None  # (family, reused) after each family


@dataclass(frozen=True)
class StudyResults:
    """What a finished families study says, per family: the judged error per trial of each
    method (label → (trials,)), and the reference the scores are normalised by."""

    seed: int  # benchmark seed
    level: float  # the bootstrap's interval level
    resamples: int  # the bootstrap's resamples
    errors: dict[str, dict[str, np.ndarray]]  # family → label → error per trial
    references: dict[str, str]  # family → the reference method's label


@runtime_checkable
class FamiliesStudy(Protocol):
    """A problem's ``qkf study families``."""

    reference: str
    """The method the policies' scores are normalised by (error_reference / error_policy);
    a study's baselines must include it."""

    def default_baselines(self) -> list[str]:
        """The study preset's methods: the baselines when none are named."""
        ...

    def check(self, run: StudyRun, level: float) -> None:
        """Everything the run would refuse, before any work (``ConfigError``): the families,
        the methods, every family's config with the overrides, the workload, and a bootstrap
        level other than ``level``."""
        ...

    def check_output(self, out: Path) -> None:
        """``OutputError`` unless ``out`` is empty, absent, or an earlier study (of which a
        finished family is kept), before any work."""
        ...

    def run(
        self, run: StudyRun, out: Path, events: StudyEvents | None = None, cache: bool = False
    ) -> None:
        """Run the study into ``out`` (the judged families and the shift group), resuming a
        family finished there earlier with the same inputs, reporting to ``events``. Writes
        ``families.md``, ``families.csv`` and each family's ``trials.csv`` in its case folder
        (:func:`qkf.core.campaign.case_folder`)."""
        ...

    def results(self, out: Path, families: Sequence[str]) -> StudyResults:
        """The judged errors per trial of ``families`` in the finished study ``out``."""
        ...


__all__ = ["Bench", "FamiliesStudy", "StudyEvents", "StudyResults", "StudyRun"]
