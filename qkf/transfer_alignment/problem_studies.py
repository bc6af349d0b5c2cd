"""Transfer alignment's benchmark and families study as the experiments layer reaches them
(:class:`qkf.core.studies.Bench`, :class:`qkf.core.studies.FamiliesStudy`): ``qkf evaluate``,
and a zoo entry's ``judge:`` and ``families:`` sections, through ``PROBLEMS[...].bench`` and
``.families_study``. Every heavy module is imported when a member is called.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from qkf.core.config import ConfigError
from qkf.core.studies import StudyEvents, StudyResults, StudyRun

if TYPE_CHECKING:
    from qkf.transfer_alignment.config import Config
    from qkf.transfer_alignment.methods import NamedMethod

FAMILIES_STUDY = "families"
"""The study preset (configs/transfer_alignment/studies/families.yaml) the families study runs,
whose method list is the default baselines."""


@dataclass(frozen=True)
class PreparedBench:
    """A benchmark checked before any work: the resolved config and methods."""

    cfg: Config
    methods: list[NamedMethod]
    trials: int


class TransferAlignmentBench:
    """``qkf bench``: :func:`~.benchmark.run_benchmark` and :func:`~.results.write_bench`."""

    def quick_baselines(self, cfg: Any, cache: bool) -> list[str]:
        """``kf``, and ``kf-tuned`` where its tuning of ``cfg`` is in the results cache."""
        from qkf.core.results_cache import cache_enabled
        from qkf.transfer_alignment.chunk_cache import preparation_cached
        from qkf.transfer_alignment.methods import METHODS

        tuned = cache and cache_enabled() and preparation_cached(METHODS["kf-tuned"], cfg)
        return ["kf", "kf-tuned"] if tuned else ["kf"]

    def prepare(self, cfg: Any, specs: Sequence[str], trials: int, source: str) -> PreparedBench:
        """:func:`~.benchmark.parse_methods`, the methods' settings sections
        (:func:`~.methods.resolve_method_settings`) and :func:`~.config.check_workload`."""
        from qkf.transfer_alignment.benchmark import parse_methods
        from qkf.transfer_alignment.config import check_workload
        from qkf.transfer_alignment.methods import resolve_method_settings

        named = parse_methods(list(specs))
        resolved = resolve_method_settings(cfg, named, source)
        try:
            check_workload(resolved, trials)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        return PreparedBench(resolved, named, trials)

    def run(
        self,
        prepared: PreparedBench,
        seed: int,
        folder: Path,
        progress: bool = False,
        cache: bool = False,
    ) -> None:
        """The benchmark's files (:func:`~.results.write_bench`) into ``folder``."""
        from qkf.transfer_alignment.benchmark import run_benchmark
        from qkf.transfer_alignment.results import write_bench

        res = run_benchmark(
            prepared.cfg, prepared.methods, prepared.trials, seed, progress=progress, cache=cache
        )
        write_bench(res, folder)


class TransferAlignmentFamiliesStudy:
    """``qkf study families --shift`` (:func:`~.campaigns.run_study` of the ``families``
    preset), judged on ``state_settled`` against ``kf-tuned`` (``kf-tuned-mixed`` on a shift
    family: :func:`~.families.reference_of`)."""

    reference = "kf-tuned"

    def default_baselines(self) -> list[str]:
        """The ``methods:`` of the ``families`` study preset."""
        from qkf.core import presets
        from qkf.core.config import read_yaml_mapping
        from qkf.transfer_alignment.config import STUDIES

        path = presets.resolve(FAMILIES_STUDY, STUDIES)
        methods = read_yaml_mapping(path, "study").get("methods")
        if not isinstance(methods, list) or not all(isinstance(m, str) for m in methods):
            raise ValueError(f"{path}: methods: not a list of method specs")
        return list(methods)

    def check(self, run: StudyRun, level: float) -> None:
        """:func:`~.study.load_study`, each family's workload and bootstrap level."""
        from qkf.transfer_alignment.config import check_workload
        from qkf.transfer_alignment.study import load_study, study_cases

        study, configs = load_study(
            FAMILIES_STUDY, list(run.sets), families=list(run.families),
            methods=list(run.policies), seed=run.seed, base_methods=list(run.baselines),
            shift=True,
        )  # fmt: skip
        for case, cfg in zip(study_cases(study), configs, strict=True):
            try:
                check_workload(cfg, run.trials)
            except ConfigError as exc:
                raise ConfigError(f"{case.label}: {exc}") from None
            if cfg.run.bootstrap.level != level:
                raise ConfigError(
                    f"{case.label}: run.bootstrap.level: {cfg.run.bootstrap.level:g}; the "
                    f"results are reported at {100 * level:g} % (leave it at {level:g})"
                )

    def check_output(self, out: Path) -> None:
        """:func:`~.cases.prepare_output`, resuming (``OutputError``)."""
        from qkf.transfer_alignment.cases import prepare_output

        prepare_output(out, resume=True, overwrite=False)

    def run(
        self, run: StudyRun, out: Path, events: StudyEvents | None = None, cache: bool = False
    ) -> None:
        """:func:`~.campaigns.run_study` of the ``families`` preset with the shift group,
        resuming."""
        from qkf.transfer_alignment.campaigns import run_study
        from qkf.transfer_alignment.cases import CaseRun

        said = events or StudyEvents()

        def started(i: int, n: int, case: CaseRun) -> None:
            if said.on_start is not None:
                said.on_start(i, n, case.label)

        def finished(case: CaseRun, folder: Path, reused: bool) -> None:
            if said.on_case is not None:
                said.on_case(case.label, reused)

        run_study(
            FAMILIES_STUDY, out, said.progress, resume=True, overwrite=False, on_case=finished,
            trials=run.trials, sets=list(run.sets), on_start=started,
            families=list(run.families), extra_methods=list(run.policies), seed=run.seed,
            base_methods=list(run.baselines), cache=cache, shift=True,
        )  # fmt: skip

    def results(self, out: Path, families: Sequence[str]) -> StudyResults:
        """``state_settled`` per trial of each family's ``trials.csv``; the bootstrap settings
        of the first family's bench, the seed of the study's ``run.json`` (as ``families.md``
        uses them)."""
        from qkf.core.campaign import case_folder
        from qkf.core.manifest import read_manifest
        from qkf.transfer_alignment.families import reference_of
        from qkf.transfer_alignment.metrics import METRIC_COLUMNS, STATE_SETTLED
        from qkf.transfer_alignment.results import load_bench, read_trials_csv

        seed = int(read_manifest(out, "study")["seed"])
        boot = load_bench(out / case_folder(families[0])).config.run.bootstrap
        j = METRIC_COLUMNS.index(STATE_SETTLED)
        errors, references = {}, {}
        for family in families:
            values = read_trials_csv(out / case_folder(family))
            errors[family] = {m: v[:, j] for m, v in values.items()}
            references[family] = reference_of(values)
        return StudyResults(seed, boot.level, boot.resamples, errors, references)


BENCH = TransferAlignmentBench()
FAMILIES_STUDY_RUNNER = TransferAlignmentFamiliesStudy()

__all__ = [
    "BENCH",
    "FAMILIES_STUDY",
    "FAMILIES_STUDY_RUNNER",
    "PreparedBench",
    "TransferAlignmentBench",
    "TransferAlignmentFamiliesStudy",
]
