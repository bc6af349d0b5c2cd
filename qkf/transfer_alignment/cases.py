"""The cases of transfer-alignment campaigns (studies and sweeps): what one case is, how it is
run (its CRLB and, with methods, its Monte Carlo benchmark), written and read back.

:class:`BenchCases` is this problem's :class:`qkf.core.campaign.CaseRunner`; :data:`STUDY`
and :data:`SWEEP` are its two kinds of :class:`qkf.core.campaign.Campaign`, which own the
output folder (what it may hold, resume, overwrite, ``run.json``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qkf.core.campaign import Campaign
from qkf.core.config import ConfigError
from qkf.core.io import staged_directory
from qkf.core.manifest import MANIFEST as RUN_FILE
from qkf.core.manifest import manifest, read_manifest, write_manifest
from qkf.transfer_alignment.benchmark import NEES_COLUMNS, BenchResult, run_benchmark
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.crlb import CrlbResult, crlb
from qkf.transfer_alignment.judging import state_weights
from qkf.transfer_alignment.methods import NamedMethod
from qkf.transfer_alignment.metrics import summarize
from qkf.transfer_alignment.report import INTERVAL_COLUMNS, summary_rows
from qkf.transfer_alignment.results import load_bench, write_bench, write_crlb_csv
from qkf.transfer_alignment.states import DISPLAY_UNIT


@dataclass(frozen=True)
class CaseRun:
    """One case of a study or a sweep: its label, output folder name and config."""

    label: str
    folder: str
    cfg: Config
    # the case's own method specs, when not the study's (a shift family: shift_methods)
    methods: tuple[str, ...] | None = None


@dataclass
class CaseResult:
    case: CaseRun
    bound: CrlbResult
    bench: BenchResult | None  # None for a CRLB-only study


def run_case(
    case: CaseRun,
    methods: list[Any] | None,
    trials: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    backend: str = "local",
    workers: int | None = None,
    cache: bool = False,
) -> CaseResult:
    """The CRLB of a case and, unless ``methods`` is None, its Monte Carlo benchmark
    (``cache``: that of :func:`run_benchmark`)."""
    bound = crlb(case.cfg)
    if methods is None:
        return CaseResult(case, bound, None)
    res = run_benchmark(case.cfg, methods, trials, seed, progress, backend, workers, cache=cache)
    return CaseResult(case, bound, res)


def case_rows(result: CaseResult) -> list[list[object]]:
    """Summary rows of a case, the case label first (``study.csv``, ``sweep_summary.csv``)."""
    if result.bench is None:
        cfg = result.case.cfg
        weights = state_weights(cfg) / DISPLAY_UNIT
        summary = summarize(
            result.bound.bound / DISPLAY_UNIT, result.bound.t, cfg.run.settled_s, weights
        )
        cells = [summary[c[: -len(s)] if (s := _suffix(c)) else c] for c in INTERVAL_COLUMNS]
        return [[result.case.label, "crlb", 0, 0, *cells, *[""] * len(NEES_COLUMNS), 0.0]]
    return [[result.case.label, *row] for row in summary_rows(result.bench)]


def _suffix(column: str) -> str:
    return next((s for s in ("_lo", "_hi") if column.endswith(s)), "")


def write_case(result: CaseResult, folder: Path) -> list[Path]:
    """The files of one case, written as one: those of ``qkf bench``, or ``crlb.csv`` and
    ``run.json``."""
    if result.bench is not None:
        return write_bench(result.bench, folder)
    with staged_directory(folder) as stage:
        write_crlb_csv(stage / "crlb.csv", result.bound)
        write_manifest(stage, manifest("crlb", result.case.cfg.model_dump(mode="json")))
    return [folder / "crlb.csv", folder / "run.json"]


def _finished(case: CaseRun, folder: Path, methods: list[Any], trials: int, seed: int) -> bool:
    """A case folder that holds a complete benchmark of exactly this case."""
    try:
        info = read_manifest(folder, "bench")
    except ConfigError:
        return False
    specs = [m.get("spec") for m in info.get("methods", [])]
    wanted = [m.spec if isinstance(m, NamedMethod) else m for m in methods]
    return (
        info["config"] == case.cfg.model_dump(mode="json")
        and specs == wanted
        and info.get("trials") == trials
        and info.get("seed") == seed
    )


@dataclass(frozen=True)
class BenchCases:
    """How a study or sweep runs its cases (:class:`qkf.core.campaign.CaseRunner`): the CRLB
    of each and, unless ``methods`` is None, its Monte Carlo benchmark with ``bench`` options
    (progress, backend, workers, cache: those of :func:`run_benchmark`)."""

    methods: list[Any] | None
    trials: int
    seed: int
    bench: dict[str, Any]

    def own_methods(self, case: CaseRun) -> list[Any] | None:
        """The case's methods: its own (a shift family) or the campaign's."""
        return self.methods if case.methods is None or self.methods is None else list(case.methods)

    def run(self, case: CaseRun) -> CaseResult:
        return run_case(case, self.own_methods(case), self.trials, self.seed, **self.bench)

    def write(self, result: CaseResult, folder: Path) -> None:
        write_case(result, folder)

    def reuse(self, case: CaseRun, folder: Path) -> CaseResult | None:
        own = self.own_methods(case)
        if own is None or not _finished(case, folder, own, self.trials, self.seed):
            return None  # a CRLB-only case is recomputed: it costs less than reading it back
        return CaseResult(case, crlb(case.cfg), load_bench(folder))


SUMMARY_FILES = frozenset({
    "study.csv", "study.png", "sweep_summary.csv", "families.csv", "families.md", "families.png",
    RUN_FILE,
})  # fmt: skip
"""The files a study or sweep writes beside its case folders."""


STUDY = Campaign("study", SUMMARY_FILES)


SWEEP = Campaign("sweep", SUMMARY_FILES)


CAMPAIGNS = {c.kind: c for c in (STUDY, SWEEP)}


def prepare_output(out: str | Path, resume: bool, overwrite: bool, kind: str = "study") -> None:
    """Refuse, before any work, an output folder that a study or sweep (``kind``) may not use
    (:meth:`qkf.core.campaign.Campaign.prepare`)."""
    CAMPAIGNS[kind].prepare(out, resume, overwrite)


__all__ = [
    "STUDY",
    "SWEEP",
    "BenchCases",
    "CaseResult",
    "CaseRun",
    "case_rows",
    "prepare_output",
    "run_case",
    "write_case",
]
