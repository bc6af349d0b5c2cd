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

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from qkf.core import presets
from qkf.core.campaign import case_folder
from qkf.core.config import ConfigError, StrictModel, read_yaml_mapping, validate
from qkf.core.method_specs import pick_baselines, spec_label
from qkf.transfer_alignment.benchmark import parse_methods, refuse_tuning_seed
from qkf.transfer_alignment.config import MAX_TRIALS, PRESETS, STUDIES, Config, load_config
from qkf.transfer_alignment.methods import resolve_method_settings
from qkf.transfer_alignment.metrics import METRIC_COLUMNS


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


__all__ = [
    "Case",
    "Study",
    "case_base",
    "load_study",
    "pick_baselines",
    "shift_methods",
    "spec_label",
    "study_cases",
]
