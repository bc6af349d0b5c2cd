"""Claims: statements of the form "A beats B", settled with paired bootstrap intervals.

A claims study (``kind: claims``, e.g. ``configs/transfer_alignment/studies/paper_claims.yaml``)
lists claims. Each claim is a ratio of RMS values of one metric::

    ratio = Π_numerator RMS(run) / Π_denominator RMS(run)

where a *run* is a method on a config (a base file plus ``--set`` overrides). Every run uses the
same trials (seed and trial count of the study), so trial ``i`` carries the same random draws in
all of them and the ratio is bootstrapped *paired*: trials are resampled once, jointly, and every
RMS is recomputed on the same resample. Verdict: ``reproduced`` iff the interval's upper end is
below 1, ``refuted`` iff its lower end is above 1, else ``inconclusive``. A claim that "A is less
sensitive than B to X" is the ratio ``(A@X₂ / A@X₁) / (B@X₂ / B@X₁)``: four runs.

Output: ``claims.csv`` (``claim_id``, ``claim``, ``metric``, ``method``, ``baseline``, ``ratio``,
``lo``, ``hi``, ``verdict``), ``claims.md`` (with each claim's reason for its metric and preset)
and one benchmark folder per distinct config.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from qkf.core import presets
from qkf.core.config import ConfigError, StrictModel, read_yaml_mapping, validate
from qkf.core.io import atomic_write_bytes, csv_text, slug, staged_directory
from qkf.core.manifest import manifest, write_manifest
from qkf.core.stats import bootstrap_rms, percentile_interval, ratio_side, resample_counts
from qkf.transfer_alignment.benchmark import BenchResult, parse_methods, run_benchmark
from qkf.transfer_alignment.config import STUDIES, Config, load_config
from qkf.transfer_alignment.metrics import METRIC_COLUMNS
from qkf.transfer_alignment.results import write_bench

CLAIM_COLUMNS = (
    "claim_id",
    "claim",
    "metric",
    "method",
    "baseline",
    "ratio",
    "lo",
    "hi",
    "verdict",
)


class Run(StrictModel):
    """A method on a config: ``base`` (relative to the study file) with ``set`` overrides."""

    base: str
    set: list[str] = Field(default_factory=list)
    method: str
    label: str = ""  # how the run is named in the tables (default: method @ config)


class Claim(StrictModel):
    id: str
    claim: str
    why: str = ""  # why this metric and this preset
    metric: str
    numerator: list[Run] = Field(min_length=1)
    denominator: list[Run] = Field(min_length=1)


class ClaimsStudy(StrictModel):
    name: str
    kind: Literal["claims"]
    description: str = ""
    trials: Annotated[int, Field(ge=2)] = 30
    seed: Annotated[int, Field(ge=0)] = 0
    level: Annotated[float, Field(gt=0.5, lt=1.0)] = 0.95
    resamples: Annotated[int, Field(ge=100)] = 10_000
    claims: list[Claim] = Field(min_length=1)


@dataclass(frozen=True)
class Verdict:
    claim: Claim
    method: str
    baseline: str
    ratio: float
    lo: float
    hi: float

    @property
    def verdict(self) -> str:
        """``reproduced`` (interval below 1), ``refuted`` (above 1) or ``inconclusive``."""
        return ("inconclusive", "refuted", "reproduced")[ratio_side(self.lo, self.hi)]


def load_claims(path: str | Path) -> tuple[ClaimsStudy, dict[tuple[str, tuple[str, ...]], Config]]:
    """The study and the config of every distinct (base, overrides) it uses."""
    path = presets.resolve(path, STUDIES)
    study = validate(ClaimsStudy, read_yaml_mapping(path, "study"), str(path), "study")
    configs: dict[tuple[str, tuple[str, ...]], Config] = {}
    for i, claim in enumerate(study.claims):
        if claim.metric not in METRIC_COLUMNS:
            raise ConfigError(
                f"{path}: claims.{i}.metric: must be one of {', '.join(METRIC_COLUMNS)}"
            )
        for part in ("numerator", "denominator"):
            for j, run in enumerate(getattr(claim, part)):
                where = f"{path}: claims.{i}.{part}.{j}"
                try:
                    parse_methods(run.method)
                except ValueError as exc:
                    raise ConfigError(f"{where}.method: {exc}") from None
                key = (run.base, tuple(run.set))
                if key not in configs:
                    try:
                        configs[key] = load_config((path.parent / run.base).resolve(), run.set)
                    except ConfigError as exc:
                        raise ConfigError(f"{where}: {exc}") from None
    return study, configs


def _label(run: Run, names: dict[tuple[str, tuple[str, ...]], str]) -> str:
    return run.label or f"{run.method} @ {names[(run.base, tuple(run.set))]}"


def run_claims(path: str | Path, out_dir: str | Path, progress: bool = True) -> list[Verdict]:
    """Run every config the claims need (each method once per config), then settle them."""
    study, configs = load_claims(path)
    wanted: dict[tuple[str, tuple[str, ...]], list[str]] = {key: [] for key in configs}
    for claim in study.claims:
        for run in [*claim.numerator, *claim.denominator]:
            methods = wanted[(run.base, tuple(run.set))]
            if run.method not in methods:
                methods.append(run.method)
    names = {
        key: slug(f"{Path(key[0]).stem}{'_' + '_'.join(key[1]) if key[1] else ''}").strip("_")
        for key in configs
    }
    results: dict[tuple[str, tuple[str, ...]], BenchResult] = {
        key: run_benchmark(cfg, wanted[key], study.trials, study.seed, progress)
        for key, cfg in configs.items()
    }
    counts = resample_counts(study.trials, study.resamples, study.seed)

    def product(runs: list[Run], j: int) -> tuple[float, np.ndarray]:
        """Π RMS of metric ``j`` over the runs, on all trials and on every resample."""
        point, reps = 1.0, np.ones(counts.shape[0])
        for run in runs:
            res = results[(run.base, tuple(run.set))]
            m = next(m for m in res.methods if m.name == run.method)
            assert m.trial_values is not None
            v = np.ascontiguousarray(m.trial_values[:, j])
            point *= float(np.sqrt(np.mean(v**2)))
            reps = reps * bootstrap_rms(v[:, None] ** 2, counts)[:, 0]
        return point, reps

    verdicts = []
    for claim in study.claims:
        j = METRIC_COLUMNS.index(claim.metric)
        num, num_reps = product(claim.numerator, j)
        den, den_reps = product(claim.denominator, j)
        lo, hi = percentile_interval(num_reps / den_reps, study.level)
        verdicts.append(
            Verdict(
                claim,
                " × ".join(_label(r, names) for r in claim.numerator),
                " × ".join(_label(r, names) for r in claim.denominator),
                num / den,
                float(lo),
                float(hi),
            )
        )
    rows = [
        [v.claim.id, v.claim.claim, v.claim.metric, v.method, v.baseline, v.ratio, v.lo, v.hi,
         v.verdict]
        for v in verdicts
    ]  # fmt: skip
    with staged_directory(Path(out_dir)) as stage:
        for key, res in results.items():
            write_bench(res, stage / names[key])
        atomic_write_bytes(stage / "claims.csv", csv_text(CLAIM_COLUMNS, rows).encode())
        atomic_write_bytes(stage / "claims.md", claims_markdown(study, verdicts).encode())
        write_manifest(stage, manifest("claims", study.model_dump(mode="json")))
    return verdicts


def claims_markdown(study: ClaimsStudy, verdicts: list[Verdict]) -> str:
    level = 100 * study.level
    lines = [
        f"# {study.name}",
        "",
        study.description.strip(),
        "",
        f"{study.trials} trials (seed {study.seed}) per run, the same trials in every run; "
        f"ratio of RMS values with its paired {level:g} % percentile-bootstrap interval "
        f"({study.resamples} resamples of trials). Reproduced iff the interval lies below 1, "
        "refuted iff above 1.",
        "",
        "| claim | metric | ratio | interval | verdict |",
        "|---|---|---|---|---|",
    ]
    for v in verdicts:
        lines.append(
            f"| {v.claim.id}. {v.claim.claim} | `{v.claim.metric}` | {v.ratio:.3f} | "
            f"[{v.lo:.3f}, {v.hi:.3f}] | **{v.verdict}** |"
        )
    lines += ["", "## Why these metrics and presets", ""]
    for v in verdicts:
        lines += [
            f"**{v.claim.id}. {v.claim.claim}** ({v.method} / {v.baseline}). {v.claim.why}",
            "",
        ]
    return "\n".join(lines).rstrip() + "\n"
