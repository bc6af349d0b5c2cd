"""Running transfer-alignment campaigns: a sweep (one config value over a list, ``sweep:`` in a
scenario config) and a study (named cases from a study file, :mod:`.study`), each case into
its own folder (:mod:`.cases`, :mod:`qkf.core.campaign`), then the summary files; and
redrawing a finished study's figures from its files.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from qkf.core.campaign import case_folder, run_cases
from qkf.core.config import ConfigError, validate
from qkf.core.io import atomic_write_bytes, atomic_write_csv, slug
from qkf.core.manifest import MANIFEST as RUN_FILE
from qkf.core.manifest import read_manifest
from qkf.core.plotting import figure_png
from qkf.transfer_alignment.bench_figures import bench_figures
from qkf.transfer_alignment.benchmark import parse_methods
from qkf.transfer_alignment.cases import STUDY, SWEEP, BenchCases, CaseResult, CaseRun, case_rows
from qkf.transfer_alignment.config import Config, load_config
from qkf.transfer_alignment.families import (
    FAMILIES_COLUMNS,
    FamilyRow,
    VersusRow,
    families_figure,
    families_markdown,
    family_rows,
    seed_statistics,
    versus_rows,
)
from qkf.transfer_alignment.report import SUMMARY_COLUMNS
from qkf.transfer_alignment.results import checked_rows, load_bench, read_crlb_csv, read_trials_csv
from qkf.transfer_alignment.study import Study, load_study, shift_methods, study_cases
from qkf.transfer_alignment.study_figures import study_curves, study_figure


def sweep_cases(config: str | Path, sets: list[str], cfg: Config) -> list[CaseRun]:
    """The cases of ``cfg.sweep``: the config reloaded with ``--set key=value`` per value (each
    case's own config has no sweep: its manifest reruns that case alone)."""
    assert cfg.sweep is not None
    key = cfg.sweep.key
    leaf = key.split(".")[-1]
    cases = []
    for v in cfg.sweep.values:
        case_cfg = load_config(config, [*sets, f"{key}={v}"]).model_copy(update={"sweep": None})
        cases.append(CaseRun(str(v), f"{leaf}={slug(v)}", case_cfg))
    return cases


def run_sweep(
    cases: list[CaseRun],
    key: str,
    methods: list[Any],
    out_dir: str | Path,
    trials: int | None = None,
    seed: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_case: Callable[[CaseRun, Path, bool], None] | None = None,
    **bench: Any,
) -> Path:
    """Run each case into ``OUT/<leaf>=<value>/`` (written as soon as it is done), then
    ``OUT/sweep_summary.csv``; returns the latter. ``bench``: options of ``run_benchmark``."""
    out = Path(out_dir)
    run = cases[0].cfg.run
    n, s = trials or run.trials, run.seed if seed is None else seed
    with SWEEP.output(out, resume, overwrite) as where:
        folders = [{"label": c.label, "folder": c.folder} for c in cases]
        sweep = {"sweep": {"key": key, "values": [c.label for c in cases]}}

        def record() -> None:
            SWEEP.record(where, sweep, trials=n, seed=s, cases=folders)

        def after(case: CaseRun, folder: Path, reused: bool) -> None:
            record()
            if on_case is not None:
                on_case(case, folder, reused)

        record()
        results = run_cases(cases, BenchCases(methods, n, s, bench), where, resume, after)
        rows = [row for r in results for row in case_rows(r)]
        atomic_write_csv(where / "sweep_summary.csv", (key, *SUMMARY_COLUMNS), rows)
        SWEEP.remove_stale(where, {c.folder for c in cases} | {"sweep_summary.csv", RUN_FILE})
        record()
    return out / "sweep_summary.csv"


def run_study(
    path: str | Path,
    out_dir: str | Path,
    progress: bool = True,
    resume: bool = False,
    overwrite: bool = False,
    on_case: Callable[[CaseRun, Path, bool], None] | None = None,
    *,
    trials: int | None = None,
    sets: list[str] | None = None,
    on_start: Callable[[int, int, CaseRun], None] | None = None,
    families: list[str] | None = None,
    extra_methods: list[str] | None = None,
    seed: int | None = None,
    base_methods: list[str] | None = None,
    cache: bool = False,
    baselines: list[str] | None = None,
    backend: str = "local",
    workers: int | None = None,
    shift: bool = False,
) -> list[Path]:
    """Run every case (each case folder written as soon as it is done), then ``study.csv``,
    ``study.png`` (a families study: ``families.csv``, ``families.md``, ``families.png``) and
    ``run.json``. ``trials`` replaces the study's own; ``sets`` are applied to every case after
    its own (both recorded in run.json, and in each case's manifest); ``families``,
    ``extra_methods``, ``seed``, ``base_methods``: see :func:`load_study`; ``cache``: reuse
    results from the results cache (docs/caching.md); ``backend``, ``workers``: those of
    :func:`run_benchmark` (trials, and the methods' tunings, side by side)."""
    study, configs = load_study(
        path, sets, families=families, methods=extra_methods, seed=seed,
        base_methods=base_methods, baselines=baselines, shift=shift,
    )  # fmt: skip
    out = Path(out_dir)
    n = study.trials if trials is None else trials
    methods = study.methods if study.kind != "crlb" else None
    shifted = shift_methods(study.methods) if study.kind == "families" else None
    cases = [
        CaseRun(case.label, case_folder(case.label), cfg,
                shifted if case.label in study.shift_families else None)
        for case, cfg in zip(study_cases(study), configs, strict=True)
    ]  # fmt: skip
    with STUDY.output(out, resume, overwrite) as where:
        folders = [{"label": c.label, "folder": c.folder} for c in cases]

        def record() -> None:
            STUDY.record(
                where, study.model_dump(mode="json"), study=str(path), trials=n,
                seed=study.seed, sets=list(sets or []), cases=folders,
            )  # fmt: skip

        def after(case: CaseRun, folder: Path, reused: bool) -> None:
            record()
            if on_case is not None:
                on_case(case, folder, reused)

        record()
        bench = {"progress": progress, "cache": cache, "backend": backend, "workers": workers}
        runner = BenchCases(methods, n, study.seed, bench)
        results = run_cases(cases, runner, where, resume, after, on_start)
        rows = [row for r in results for row in case_rows(r)]
        atomic_write_csv(where / "study.csv", ("case", *SUMMARY_COLUMNS), rows)
        level = configs[0].run.bootstrap.level
        if study.kind == "families":
            figures = write_families(where, study, cases, configs[0], n, results)
        else:
            png = figure_png(study_figure(study, study_curves(results), rows, level))
            atomic_write_bytes(where / "study.png", png)
            figures = ["study.png"]
        STUDY.remove_stale(where, {c.folder for c in cases} | {"study.csv", *figures, RUN_FILE})
        record()
    return [*(out / c.folder for c in cases), out / "study.csv", *(out / f for f in figures)]


def write_families(
    where: Path,
    study: Study,
    cases: list[CaseRun],
    cfg: Config,
    trials: int,
    results: list[CaseResult] | None = None,
) -> list[str]:
    """``families.csv``, ``families.md`` and ``families.png`` of a families study, from its
    case folders in ``where`` (qkf.transfer_alignment.families); returns the file names."""
    boot = cfg.run.bootstrap
    rows: list[FamilyRow] = []
    seeds: dict[str, list[dict[str, object]]] = {}
    from qkf.transfer_alignment.methods import METHODS

    # the methods a reviewer asks about: those that are not registered methods (a policy,
    # a method of one's own), each judged against every other method of the family
    labels = [m.name for m in parse_methods(study.methods)]
    focus = [m for m in labels if m not in METHODS]
    versus: list[VersusRow] = []
    for case in cases:
        folder = where / case.folder
        values = read_trials_csv(folder)  # once per case, for every table below
        rows += family_rows(case.label, folder, values, boot.resamples, boot.level, study.seed)
        versus += versus_rows(case.label, values, focus, boot.resamples, boot.level, study.seed)
        stats = seed_statistics(values, list(values), boot.level, seed=study.seed)
        if stats:
            seeds[case.label] = stats
    notes: dict[str, str] = {}
    certificates: dict[str, str] = {}  # per family: hindsight's restarts (it differs by family)
    for r in results or []:
        for m in r.bench.methods if r.bench is not None else []:
            for key, text in m.notes.items():
                if key == "hindsight_certificate":
                    certificates[r.case.label] = text
                else:
                    notes.setdefault(m.name, text)
    families = [c.label for c in cases]
    atomic_write_csv(where / "families.csv", FAMILIES_COLUMNS, [r.cells() for r in rows])
    text = families_markdown(
        rows, families, trials, study.seed, boot.level, notes, seeds, versus, certificates
    )
    atomic_write_bytes(where / "families.md", text.encode())
    png = figure_png(families_figure(rows, families, boot.level))
    atomic_write_bytes(where / "families.png", png)
    return ["families.csv", "families.md", "families.png"]


def redraw_study(folder: str | Path) -> list[Path]:
    """Redraw the figures of a finished study from its files, without rerunning anything: each
    bench case's figures (from its CSV files) and ``study.png`` (from ``study.csv``, the cases'
    CRLBs and RMS curves, and ``run.json``). Returns the figures written; ``ConfigError`` names
    the file (and line) that cannot be read."""
    folder = Path(folder)
    manifest_path = folder / RUN_FILE
    if not manifest_path.is_file():
        raise ConfigError(
            f"{manifest_path}: missing (a study folder written by an earlier qkf); "
            f"qkf study STUDY --out {folder} --resume writes it and redraws the study "
            "(finished bench cases are kept, not rerun)"
        )
    info = read_manifest(folder, "study")
    study = validate(Study, info["config"], str(manifest_path), "study")
    study_csv = folder / "study.csv"
    table = _read_study_csv(study_csv)
    loaded: list[tuple[CaseResult, dict[str, bytes]]] = []
    cases = study_cases(study)
    for case in cases:  # read everything first: a bad file leaves every figure as it was
        where = folder / case_folder(case.label)
        if study.kind != "crlb":
            bench = load_bench(where)
            run = CaseRun(case.label, where.name, bench.config)
            loaded.append((CaseResult(run, bench.bound, bench), bench_figures(bench)))
        else:
            cfg_info = read_manifest(where, "crlb")
            cfg = validate(Config, cfg_info["config"], str(where / RUN_FILE), "configuration")
            bound = read_crlb_csv(where / "crlb.csv")
            loaded.append((CaseResult(CaseRun(case.label, where.name, cfg), bound, None), {}))
    labels = [c.label for c in cases]
    missing = [lab for lab in labels if lab not in {r[0] for r in table}]
    if missing:
        raise ConfigError(f"{study_csv}: no row of case {missing[0]!r} (a truncated file?)")
    results = [r for r, _ in loaded]
    level = results[0].case.cfg.run.bootstrap.level
    png = None
    if study.kind != "families":
        png = figure_png(study_figure(study, study_curves(results), table, level))
    written = []
    for result, figures in loaded:
        for name, content in figures.items():
            atomic_write_bytes(folder / result.case.folder / name, content)
            written.append(folder / result.case.folder / name)
    if png is None:
        runs = [r.case for r in results]
        names = write_families(folder, study, runs, results[0].case.cfg, int(info["trials"]))
        return [*written, *(folder / n for n in names if n.endswith(".png"))]
    atomic_write_bytes(folder / "study.png", png)
    return [*written, folder / "study.png"]


def _read_study_csv(path: Path) -> list[list[object]]:
    """``study.csv`` back as the rows :func:`study_figure` takes (text cells), checked: every
    row complete, the plotted columns numbers (or empty); ``ConfigError`` names the line."""
    header = ["case", *SUMMARY_COLUMNS]

    def header_problem(found: list[str]) -> str | None:
        return None if found == header else "line 1: not the header of a qkf study.csv"

    rows: list[list[object]] = []
    for _, line, cells in checked_rows(path, "qkf study folder", header_problem):
        for col, cell in zip(header[4:], cells[4:], strict=True):
            try:
                float(cell or "nan")
            except ValueError:
                raise ConfigError(f"{path}: line {line}: {col}: {cell!r} is not a number") from None
        rows.append(list(cells))
    return rows


__all__ = [
    "redraw_study",
    "run_study",
    "run_sweep",
    "sweep_cases",
    "write_families",
]
