"""Studies: one command that runs a set of cases (benchmarks or CRLBs) and plots them together.

A study file (``configs/transfer_alignment/studies/*.yaml``)::

    name: matching
    kind: bench                 # bench: Monte Carlo of ``methods``; crlb: the bound only
    base: ../paper.yaml         # config every case starts from (relative to the study file)
    methods: [kf]
    trials: 50
    seed: 0
    metric: att_arcsec_avg      # summary column plotted against the cases
    cases:
      - {label: attitude, set: [filter.matching=attitude]}
      - {label: attitude + rate, set: [filter.matching=attitude_rate]}

A ``base`` is a path relative to the study file or, if no such file exists, a preset name
(``base: paper``); a case may name its own. Labels must differ, also once made file-name safe
(each names its case folder). Output: one folder per case (the files of ``qkf bench`` or
``crlb.csv``), ``study.csv`` (one row per case and method), ``study.png`` and ``run.json`` (the
study, the trials and ``--set`` overrides in effect, the cases and their folders: what
``qkf plot`` needs to redraw it).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from qkf.core import presets
from qkf.core.config import ConfigError, StrictModel, read_yaml_mapping, validate
from qkf.core.io import (
    OutputError,
    atomic_write_bytes,
    atomic_write_csv,
    check_output_dir,
    slug,
    staged_directory,
)
from qkf.core.manifest import MANIFEST as RUN_FILE
from qkf.core.manifest import manifest, read_manifest, write_manifest
from qkf.core.plotting import Figure, figure_png, plt
from qkf.transfer_alignment.benchmark import (
    NEES_COLUMNS,
    BenchResult,
    parse_methods,
    refuse_tuning_seed,
    run_benchmark,
)
from qkf.transfer_alignment.config import (
    MAX_TRIALS,
    PRESETS,
    STUDIES,
    Config,
    load_config,
)
from qkf.transfer_alignment.crlb import CrlbResult, crlb
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
from qkf.transfer_alignment.judging import state_weights
from qkf.transfer_alignment.methods import NamedMethod, resolve_method_settings
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, group_rms, summarize
from qkf.transfer_alignment.report import (
    INTERVAL_COLUMNS,
    SUMMARY_COLUMNS,
    UNITS,
    bench_figures,
    checked_rows,
    load_bench,
    method_style,
    read_crlb_csv,
    read_trials_csv,
    summary_rows,
    write_bench,
    write_crlb_csv,
)
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES


class Case(StrictModel):
    label: str
    base: str | None = None
    set: list[str] = Field(default_factory=list)


class Study(StrictModel):
    """A study file. ``kind: families`` lists ``families`` (preset names) instead of ``base``
    and ``cases``: each family is a case, run from its preset (qkf.transfer_alignment.families)."""

    name: str
    description: str = ""
    kind: Literal["bench", "crlb", "families"] = "bench"
    base: str | None = None
    methods: list[str] = Field(default_factory=lambda: ["kf"])
    trials: Annotated[int, Field(ge=1, le=MAX_TRIALS)] = 20
    seed: Annotated[int, Field(ge=0)] = 0
    metric: str = "state_settled"
    cases: list[Case] = Field(default_factory=list)
    families: list[str] = Field(default_factory=list)
    # kind: families: the shift group, judged with --shift only (docs/models.md, "Shift group")
    shift_families: list[str] = Field(default_factory=list)

    @model_validator(mode="after")
    def _shape(self) -> Study:
        if self.kind == "families":
            if self.cases or self.base is not None:
                raise ValueError("a families study lists families, not base and cases")
            if not self.families:
                raise ValueError("families: at least one family")
        else:
            if self.base is None:
                raise ValueError("base: required")
            if not self.cases:
                raise ValueError("cases: at least one case")
            if self.families or self.shift_families:
                raise ValueError("families: only for kind: families")
        return self


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


def case_folder(label: str) -> str:
    """The folder of a study case: its label made file-name safe (``attitude + rate`` →
    ``attitude_rate``)."""
    return slug(label).strip("_") or "case"


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


def prepare_output(out: str | Path, resume: bool, overwrite: bool, kind: str = "study") -> None:
    """Refuse, before any work, an output folder that a study or sweep (``kind``) may not use.

    A study or sweep writes each case folder whole as soon as it is done, so an interrupted run
    can be finished with ``resume`` (finished cases are read back, not recomputed), or replaced
    with ``overwrite``. A folder holding anything qkf did not write is refused whatever the
    flags (never deleted, never written into), and a refusal suggests only a flag that works.
    """
    out = check_output_dir(out)  # as given: Path('') would be the working directory
    if resume and overwrite:
        raise OutputError("--resume and --overwrite exclude each other")
    if not out.is_dir() or not any(out.iterdir()):
        return
    found = _manifest(out)
    if found is not None and found["kind"] != kind:
        raise OutputError(
            f"{out}: holds a qkf {found['kind']} run, not a {kind} run; choose another --out"
        )
    foreign = _not_ours(out, found)
    if foreign:
        shown = ", ".join(foreign[:4]) + (", …" if len(foreign) > 4 else "")
        if found is None:
            raise OutputError(
                f"{out}: holds files that are not a qkf run ({shown}); "
                "choose another --out or empty the folder"
            )
        raise OutputError(
            f"{out}: holds files qkf did not write beside its earlier {kind} run ({shown}); "
            "move them out of the folder or choose another --out"
        )
    try:
        # replaced whole at the end only if it holds nothing but an earlier run of this kind
        # (qkf.core.io.staged_directory): checked now, not after the work
        check_output_dir(out, kind)
        replaceable = None
    except OutputError as exc:
        replaceable = exc
    if overwrite and replaceable is not None:
        raise replaceable
    if not (resume or overwrite):
        hint = "--resume finishes it" + (", --overwrite replaces it" if replaceable is None else "")
        raise OutputError(f"{out}: holds an earlier qkf {kind} run; {hint}")


_SUMMARY_FILES = {
    "study.csv", "study.png", "sweep_summary.csv", "families.csv", "families.md", "families.png",
    RUN_FILE,
}  # fmt: skip
"""The files a study or sweep writes beside its case folders."""


def _manifest(folder: Path) -> dict[str, Any] | None:
    """The qkf manifest (``run.json``) of ``folder``, or None if it holds none."""
    try:
        return read_manifest(folder)
    except (ConfigError, OSError):
        return None


def _listed(info: dict[str, Any] | None) -> set[str]:
    """The files a manifest says its run wrote (relative to its folder)."""
    files = None if info is None else info.get("files")
    return set(map(str, files)) if isinstance(files, list) else set()


def _not_ours(out: Path, root: dict[str, Any] | None) -> list[str]:
    """What no study or sweep wrote in ``out``, as paths relative to it (a folder with a
    trailing ``/``): any file but those the folder's ``run.json`` (``root``) or a case folder's
    own lists, the summary files and qkf's hidden staging folders. Without a ``run.json``,
    ``out`` holds no study or sweep: all its entries."""
    if root is None:
        return [f"{e.name}/" if e.is_dir() else e.name for e in sorted(out.iterdir())]
    listed = _listed(root)
    found = []
    for entry in sorted(out.iterdir()):
        if entry.name.startswith("."):
            continue
        if not entry.is_dir():
            if entry.name not in listed and entry.name not in _SUMMARY_FILES:
                found.append(entry.name)
            continue
        own = _listed(_manifest(entry))
        for p in sorted(entry.rglob("*")):
            rel = p.relative_to(entry).as_posix()
            if not p.is_dir() and rel not in own and f"{entry.name}/{rel}" not in listed:
                found.append(f"{entry.name}/{rel}")
        if not any(entry.iterdir()):
            found.append(f"{entry.name}/")
    return found


def _write_root_manifest(where: Path, kind: str, config: dict[str, Any], **run: Any) -> None:
    """``run.json`` of a study or sweep folder, with the list of every file under it (so that
    ``--overwrite`` may replace exactly these). Rewritten after each case: an interrupted run
    is a complete description of what it holds."""
    data = manifest(kind, config, **run)
    files = {p.relative_to(where).as_posix() for p in where.rglob("*") if p.is_file()}
    data["files"] = sorted(files | {RUN_FILE})
    write_manifest(where, data)


def run_cases(
    cases: list[CaseRun],
    methods: list[Any] | None,
    out: Path,
    trials: int,
    seed: int,
    resume: bool = False,
    on_case: Callable[[CaseRun, Path, bool], None] | None = None,
    on_start: Callable[[int, int, CaseRun], None] | None = None,
    **bench: Any,
) -> list[CaseResult]:
    """Run the cases into ``out/<case folder>/``, each written whole as soon as it is done;
    with ``resume``, a case whose folder already holds its complete run (same config, methods,
    trials and seed) is read back instead. ``on_start(i, n, case)`` (1-based ``i`` of ``n``) is
    called before each case, ``on_case(case, folder, reused)`` after each. ``bench``:
    ``run_benchmark`` options (progress, backend, workers)."""
    results = []
    for i, case in enumerate(cases, 1):
        if on_start is not None:
            on_start(i, len(cases), case)
        folder = out / case.folder
        own = methods if case.methods is None or methods is None else list(case.methods)
        reused = resume and own is not None and _finished(case, folder, own, trials, seed)
        if reused:
            result = CaseResult(case, crlb(case.cfg), load_bench(folder))
        else:
            result = run_case(case, own, trials, seed, **bench)
            write_case(result, folder)
        results.append(result)
        if on_case is not None:
            on_case(case, folder, reused)
    return results


def _remove_stale(out: Path, keep: set[str]) -> None:
    """Remove what an earlier run left in ``out`` that this run did not write: case folders
    (recognised by their ``run.json``) and the summary files of studies and sweeps."""
    for entry in out.iterdir():
        if entry.name in keep:
            continue
        if entry.is_dir() and (entry / RUN_FILE).is_file():
            shutil.rmtree(entry)
        elif entry.is_file() and entry.name in _SUMMARY_FILES:
            entry.unlink()


@contextmanager
def _output(out: Path, resume: bool, overwrite: bool, kind: str) -> Iterator[Path]:
    """Where a study or sweep (``kind``) writes: ``out`` itself (fresh or resumed), or, with
    ``overwrite``, a staging folder swapped in whole at the end."""
    prepare_output(out, resume, overwrite, kind)
    if overwrite:
        with staged_directory(out) as stage:
            yield stage
    else:
        out.mkdir(parents=True, exist_ok=True)
        yield out


# ---- sweeps: one config value over a list (``sweep:`` in a scenario config) -------------------


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
    with _output(out, resume, overwrite, "sweep") as where:
        folders = [{"label": c.label, "folder": c.folder} for c in cases]
        sweep = {"sweep": {"key": key, "values": [c.label for c in cases]}}

        def record() -> None:
            _write_root_manifest(where, "sweep", sweep, trials=n, seed=s, cases=folders)

        def after(case: CaseRun, folder: Path, reused: bool) -> None:
            record()
            if on_case is not None:
                on_case(case, folder, reused)

        record()
        results = run_cases(cases, methods, where, n, s, resume, after, **bench)
        rows = [row for r in results for row in case_rows(r)]
        atomic_write_csv(where / "sweep_summary.csv", (key, *SUMMARY_COLUMNS), rows)
        _remove_stale(where, {c.folder for c in cases} | {"sweep_summary.csv", RUN_FILE})
        record()
    return out / "sweep_summary.csv"


# ---- studies: named cases from a study file, plotted together --------------------------------


def load_study(
    path: str | Path,
    sets: list[str] | None = None,
    *,
    families: list[str] | None = None,
    methods: list[str] | None = None,
    seed: int | None = None,
    base_methods: list[str] | None = None,
    baselines: list[str] | None = None,
    shift: bool = False,
) -> tuple[Study, list[Config]]:
    """Read a study (a path or a preset name) and the config of each case; ``sets``
    (``dotted.key=value``) are applied to every case after the case's own. ``families``: run
    only these families of a families study; ``base_methods``: replace the study's methods
    (``methods`` are added after them); ``methods``: added to the study's methods;
    ``seed``: replaces the study's seed (each recorded in the returned study); ``baselines``:
    keep only these of the study's methods (by label), before ``methods`` are added;
    ``shift``: a families study also runs its ``shift_families`` (after ``families``).

    ``ConfigError`` names the study file and, for a case, its index and label.
    """
    path = presets.resolve(path, STUDIES)
    study = validate(Study, read_yaml_mapping(path, "study"), str(path), "study")
    study = _narrow(path, study, families, methods, seed, base_methods, baselines, shift)
    # a CRLB study plots the same summary columns (of the bound), so the same names apply
    if study.metric not in METRIC_COLUMNS:
        raise ConfigError(f"{path}: metric: must be one of {', '.join(METRIC_COLUMNS)}")
    named = []
    if study.kind != "crlb":
        try:
            named = parse_methods(study.methods)
        except ValueError as exc:
            raise ConfigError(f"{path}: methods: {exc}") from None
    _check_labels(path, study)
    if study.kind != "crlb":
        try:
            refuse_tuning_seed(named, study.seed)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
    configs = []
    for i, case in enumerate(study_cases(study)):
        try:
            base = case_base(path, case.base or study.base or "")
            cfg = load_config(base, [*case.set, *(sets or [])])
            # every case's method settings checked now, not when its turn comes
            configs.append(resolve_method_settings(cfg, named, str(base)))
        except ConfigError as exc:
            raise ConfigError(f"{path}: cases.{i} ({case.label}): {exc}") from None
    return study, configs


def _narrow(
    path: Path,
    study: Study,
    families: list[str] | None,
    methods: list[str] | None,
    seed: int | None,
    base_methods: list[str] | None = None,
    baselines: list[str] | None = None,
    shift: bool = False,
) -> Study:
    """The study with the command line's choices applied: only the chosen families of a
    families study (the shift group with ``shift``), ``base_methods`` instead of its methods,
    only the ``baselines`` among them, ``methods`` added, the seed."""
    update: dict[str, Any] = {}
    if base_methods is not None:
        if study.kind == "crlb":
            raise ConfigError(f"methods: {path} is a CRLB study; it runs no method")
        if not base_methods:
            raise ConfigError(f"methods: none given to replace those of {path}")
        study = study.model_copy(update={"methods": list(base_methods)})
    if baselines is not None:
        study = study.model_copy(update={"methods": pick_baselines(study.methods, baselines)})
    if shift and study.kind != "families":
        raise ConfigError(f"--shift: {path} is a {study.kind} study, not a families study")
    if shift and not study.shift_families:
        raise ConfigError(f"--shift: {path} lists no shift_families")
    known = [*study.families, *study.shift_families]
    if families is not None:
        if study.kind != "families":
            raise ConfigError(f"--families: {path} is a {study.kind} study, not a families study")
        unknown = [f for f in families if f not in known]
        if unknown or not families:
            raise ConfigError(
                f"--families: {', '.join(unknown) or 'none given'}: not a family of {path.name}; "
                f"known: {', '.join(known)}"
            )
        chosen = list(dict.fromkeys(families))
        update["families"] = [f for f in chosen if f in study.families]
        picked = [f for f in chosen if f in study.shift_families]
        update["shift_families"] = list(study.shift_families) if shift else picked
    elif not shift:
        update["shift_families"] = []
    if study.kind == "families" and not (
        update.get("families", study.families) or update.get("shift_families", study.shift_families)
    ):
        raise ConfigError(f"--families: {path}: no family left to run")
    if methods:
        if study.kind == "crlb":
            raise ConfigError(f"--methods: {path} is a CRLB study; it runs no method")
        update["methods"] = [*study.methods, *methods]
    if seed is not None:
        update["seed"] = seed
    return study.model_copy(update=update)


def spec_label(spec: str) -> str:
    """The label a method spec is reported under, as written (``LABEL=SPEC``: LABEL)."""
    label, sep, _ = spec.partition("=")
    return label.strip() if sep else spec.strip()


def pick_baselines(specs: list[str], wanted: list[str]) -> list[str]:
    """The specs of ``specs`` whose labels are in ``wanted``, in their order; ``ConfigError``
    for a wanted label that is not there (naming those that are), or for none wanted."""
    labels = [spec_label(s) for s in specs]
    unknown = [w for w in wanted if w not in labels]
    if unknown or not wanted:
        raise ConfigError(
            f"--baselines: {', '.join(unknown) or 'none given'}: not among the methods; "
            f"choose from {', '.join(labels)}"
        )
    return [s for s, label in zip(specs, labels, strict=True) if label in wanted]


def study_cases(study: Study) -> list[Case]:
    """The cases of a study: its own, or one per family (label and base = the preset name)."""
    if study.kind == "families":
        return [Case(label=f, base=f) for f in [*study.families, *study.shift_families]]
    return list(study.cases)


def shift_methods(specs: list[str]) -> tuple[str, ...]:
    """The methods of a shift family (nothing tunes on it): each method that tunes on the
    judged config's tuning seeds (:data:`~qkf.transfer_alignment.methods.TUNABLE`, and the
    ``oracle``, which has no ``-mixed`` variant) is replaced by its ``-mixed`` twin, tuned on
    the training mixture (:mod:`~qkf.transfer_alignment.methods.on_mixture`); the oracle is
    left out."""
    from qkf.transfer_alignment.methods import MIXED_SUFFIX, TUNABLE

    out: list[str] = []
    for spec in specs:
        label, sep, target = spec.partition("=")
        name = (target if sep else spec).strip()
        if name == "oracle":
            continue
        if name in TUNABLE:
            twin = name + MIXED_SUFFIX
            spec = f"{label.strip()}{MIXED_SUFFIX}={twin}" if sep else twin
        out.append(spec)
    return tuple(dict.fromkeys(out))


def _check_labels(path: Path, study: Study) -> None:
    """Refuse two cases with one label, or with labels that give one case folder: the second
    would overwrite the first's folder and rows."""
    first: dict[str, int] = {}
    cases = study_cases(study)
    for j, case in enumerate(cases):
        folder = case_folder(case.label)
        i = first.setdefault(folder, j)
        if i == j:
            continue
        other = cases[i].label
        if other == case.label:
            raise ConfigError(
                f"{path}: cases.{j}.label: {case.label!r} is also the label of cases.{i}; "
                "each case needs a label of its own (it names the case's folder and rows)"
            )
        raise ConfigError(
            f"{path}: cases.{j}.label: {case.label!r} and cases.{i}.label {other!r} give the "
            f"same case folder {folder!r}; make them differ in letters or digits"
        )


def case_base(study_path: Path, base: str) -> Path:
    """A case's base config: the path relative to the study file if it exists, else the preset
    of that name (``base: paper``), else the relative path (reported missing by the loader)."""
    rel = study_path.parent / base
    if rel.exists():
        return rel.resolve()
    # by name only, never relative to the working directory
    return presets.preset_path(base, PRESETS) or rel


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
    with _output(out, resume, overwrite, "study") as where:
        folders = [{"label": c.label, "folder": c.folder} for c in cases]

        def record() -> None:
            _write_root_manifest(
                where, "study", study.model_dump(mode="json"), study=str(path), trials=n,
                seed=study.seed, sets=list(sets or []), cases=folders,
            )  # fmt: skip

        def after(case: CaseRun, folder: Path, reused: bool) -> None:
            record()
            if on_case is not None:
                on_case(case, folder, reused)

        record()
        results = run_cases(
            cases, methods, where, n, study.seed, resume, after, on_start, progress=progress,
            cache=cache, backend=backend, workers=workers,
        )  # fmt: skip
        rows = [row for r in results for row in case_rows(r)]
        atomic_write_csv(where / "study.csv", ("case", *SUMMARY_COLUMNS), rows)
        level = configs[0].run.bootstrap.level
        if study.kind == "families":
            figures = write_families(where, study, cases, configs[0], n, results)
        else:
            png = figure_png(study_figure(study, _curves(results), rows, level))
            atomic_write_bytes(where / "study.png", png)
            figures = ["study.png"]
        _remove_stale(where, {c.folder for c in cases} | {"study.csv", *figures, RUN_FILE})
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
        png = figure_png(study_figure(study, _curves(results), table, level))
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


Curve = tuple[str, str, np.ndarray, dict[str, np.ndarray]]  # case, method, t, group RMS


def _curves(results: list[CaseResult]) -> list[Curve]:
    curves: list[Curve] = []
    for r in results:
        t = r.bound.t
        curves.append((r.case.label, "CRLB", t, group_rms((r.bound.bound / DISPLAY_UNIT) ** 2)))
        for m in r.bench.methods if r.bench is not None else []:
            curves.append((r.case.label, m.name, t, group_rms((m.rms / DISPLAY_UNIT) ** 2)))
    return curves


def study_figure(
    study: Study, curves: list[Curve], rows: list[list[object]], level: float
) -> Figure:
    """The study's figure: RMS (and CRLB) vs time per state group, then the study's metric per
    case and method. A bench study gets small multiples, one row per group and one column per
    case (colour: method, the same everywhere; dashed black: the CRLB; y shared along a row);
    a CRLB study one panel per group with one colour per case. One legend, outside the data."""
    cases = [c.label for c in study_cases(study)]
    methods = list(dict.fromkeys(str(r[1]) for r in rows))
    color = {m: method_style(i, 2)["color"] for i, m in enumerate(methods)}
    bench = study.kind == "bench"
    ncols = len(cases) if bench else 2
    nrows = len(GROUP_TITLES) if bench else 2
    fig = plt.figure(figsize=(max(10.0, 3.3 * ncols + 1.5), 2.5 * nrows + 4.5),
                     layout="constrained")  # fmt: skip
    grid = fig.add_gridspec(nrows + 1, ncols, height_ratios=[1.0] * nrows + [1.5])
    axes = []
    for gi, (g, title) in enumerate(GROUP_TITLES.items()):
        name = title.split(" [")[0]
        if bench:
            first = None
            for ci, case in enumerate(cases):
                ax = fig.add_subplot(grid[gi, ci], sharey=first)
                first = first or ax
                for c, what, t, groups in curves:
                    if c != case:
                        continue
                    if what == "CRLB":
                        ax.semilogy(t, groups[g], "k--", lw=0.9, label="CRLB (1σ)")
                    else:
                        ax.semilogy(t, groups[g], color=color.get(what, "0.5"), lw=1.3,
                                    label=what)  # fmt: skip
                if gi == 0:
                    ax.set_title(case, fontsize=10)
                if ci == 0:
                    ax.set_ylabel(f"{name}\nRMS [{UNITS[g]}]")
                if gi == nrows - 1:
                    ax.set_xlabel("time [s]")
                ax.grid(True, which="both", alpha=0.3)
                axes.append(ax)
        else:
            ax = fig.add_subplot(grid[gi // 2, gi % 2])
            for c, _, t, groups in curves:
                ax.semilogy(t, groups[g], lw=1.3, label=c,
                            color=method_style(cases.index(c), 2)["color"])  # fmt: skip
            ax.set_title(f"{name}: CRLB (1σ)", fontsize=10)
            ax.set_ylabel(f"CRLB [{UNITS[g]}]")
            ax.set_xlabel("time [s]")
            ax.grid(True, which="both", alpha=0.3)
            axes.append(ax)
    ax = fig.add_subplot(grid[nrows, :])
    col = SUMMARY_COLUMNS.index(study.metric) + 1  # rows carry the case label first
    width = 0.8 / max(1, len(methods))
    for j, m in enumerate(methods):
        cells = [next((r for r in rows if r[0] == lab and r[1] == m), None) for lab in cases]
        vals = np.array([_cell(r[col]) if r else np.nan for r in cells])
        err = None
        if bench:
            lo = np.array([_cell(r[col + 1]) if r else np.nan for r in cells])
            hi = np.array([_cell(r[col + 2]) if r else np.nan for r in cells])
            err = np.vstack([vals - lo, hi - vals])
        # a CRLB study: each case's bar in the colour of its curves above
        shade = (
            color.get(m, "0.5")
            if bench
            else [method_style(i, 2)["color"] for i in range(len(cases))]
        )
        ax.bar(np.arange(len(cases)) + j * width, vals, width, yerr=err, capsize=3,
               color=shade, label=m if bench else None)  # fmt: skip
    ax.set_xticks(np.arange(len(cases)) + 0.4 - width / 2, cases, rotation=15, ha="right")
    # log only where the values span a decade or more: a log bar starts nowhere in particular,
    # so over a narrow range its length would exaggerate the differences
    shown = [_cell(r[col]) for r in rows]
    positive = [v for v in shown if np.isfinite(v) and v > 0]
    if positive and max(positive) >= 10 * min(positive):
        ax.set_yscale("log")
    group = next((g for g in UNITS if study.metric.startswith(g)), None)
    window = "settled" if group is None else study.metric[len(group) + 1 :]
    unit = "× final CRLB, all states" if group is None else UNITS[group]
    ax.set_ylabel(f"{study.metric} [{unit}]")
    if bench:
        what = (f"RMS over the {window} window, per case and method (error bars: "
                f"{100 * level:g} % bootstrap over trials)")  # fmt: skip
    else:
        what = (f"the CRLB (1σ bound) over the {window} window, per case (a bound computed, "
                "not sampled: no error bars)")  # fmt: skip
    ax.set_title(f"{study.metric}: {what}", fontsize=10)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    # one legend for the figure, below everything (the bar colours are the line colours)
    entries: dict[str, Any] = {}
    for a in axes:
        for handle, label in zip(*a.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    if "CRLB (1σ)" in entries:  # the methods first, in the order of study.csv
        entries["CRLB (1σ)"] = entries.pop("CRLB (1σ)")
    fig.legend(entries.values(), entries.keys(), loc="outside lower center",
               ncol=min(6, len(entries)), fontsize=9, frameon=False)  # fmt: skip
    fig.suptitle(f"study {study.name}" + (f": {study.description}" if study.description else ""))
    return fig


def _cell(value: object) -> float:
    """A number of a study row (a float, or its text from study.csv; empty: NaN)."""
    text = str(value)
    return float(text) if text else float("nan")


__all__ = [
    "CaseRun",
    "Study",
    "case_base",
    "case_folder",
    "load_study",
    "redraw_study",
    "run_study",
    "run_sweep",
    "study_figure",
    "sweep_cases",
]
