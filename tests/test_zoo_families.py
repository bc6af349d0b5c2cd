"""``qkf zoo evaluate`` of an entry with a ``families:`` section: the spec's validation, the
refusals before any work (a seed without its model, a seed of another environment version),
and a small run whose card is recomputed independently from the study's ``trials.csv``."""

from __future__ import annotations

import csv
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats as sps
from typer.testing import CliRunner

from agents.zoo import load_entry
from agents.zoo.entry import FamiliesJudge, ZooSpec, families_for
from qkf.cli import app
from qkf.core.config import ConfigError, validate
from qkf.core.problem import PROBLEMS
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, STATE_SETTLED
from qkf.transfer_alignment.problem import FAMILIES, SHIFT_FAMILIES
from qkf.transfer_alignment.results import read_trials_csv

runner = CliRunner()
TA = PROBLEMS["transfer_alignment"]
SOURCE = Path(__file__).resolve().parents[1] / "agents" / "zoo" / "ppo_snap_random"
"""A shipped entry whose trained seeds stand in for a fresh training (no training here)."""
SHORT = [
    "scenario.duration_s=600",
    "run.settled_s=300",
    "adaptive.tuned.trials=2",
    "run.bootstrap.resamples=400",
]


def _entry(tmp_path: Path, seeds: list[int], copied: list[int], **families: object) -> Path:
    """A fake entry ``fam`` whose ``seed_<s>/`` (for ``copied``) are those of
    ``ppo_snap_random`` (model, exact config, evaluations), judged on the families only."""
    folder = tmp_path / "fam"
    folder.mkdir()
    shutil.copy(SOURCE / "seed_0" / "config.yaml", folder / "train.yaml")
    spec = {"description": "fake", "train": "train.yaml", "seeds": seeds, "families": families}
    (folder / "zoo.yaml").write_text(yaml.safe_dump(spec))
    for s in copied:
        (folder / f"seed_{s}").mkdir()
        for name in ("model.zip", "config.yaml", "evaluations.npz"):
            shutil.copy(SOURCE / f"seed_{s}" / name, folder / f"seed_{s}" / name)
    return folder


def _tree(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_spec_defaults_and_refusals() -> None:
    """The section's shape is checked by the schema; what depends on the problem (families,
    judging seeds, largest run, metric, the study's reference and defaults) by families_for,
    each refusal naming its field."""
    spec = validate(ZooSpec, {"train": "x", "families": {}}, "zoo.yaml", "zoo entry")
    assert spec.families is not None and spec.judge is None and spec.cases() == []
    section = families_for(spec.families, TA)
    assert section.families is not None and tuple(section.families) == FAMILIES
    assert TA.families_study is not None
    assert section.baselines == TA.families_study.default_baselines()
    assert "kf-tuned" in section.baselines and "hindsight" in section.baselines
    assert (section.trials, section.seed) == (100, 9000)
    assert section.metric == "state_settled"
    refused = {
        "seed": ({"seed": 1_000_005}, "families.seed: 1000005 is not a judging seed"),
        "range": ({"seed": 5_100_000}, "not a judging seed"),
        "metric": ({"metric": "ma_urad_settled"}, "families.metric"),
        "family": ({"families": ["paper"]}, "paper: not a family"),
        "kf-tuned": ({"baselines": ["kf"]}, "must include kf-tuned"),
        "max": ({"trials": TA.max_trials + 1}, "families.trials"),
    }
    for what, (section_in, message) in refused.items():
        checked = validate(ZooSpec, {"train": "x", "families": section_in}, "zoo.yaml", "zoo")
        assert checked.families is not None
        with pytest.raises(ValueError) as err:
            families_for(checked.families, TA)
        assert message in str(err.value), what
    shape = {
        "trials": ({"trials": 1}, "families.trials"),
        "mark": ({"baselines": ["kf-tuned", "p#0=kf"]}, "p#0"),
        "twice": ({"families": ["steady_random", "steady_random"]}, "listed twice"),
    }
    for what, (section_in, message) in shape.items():
        with pytest.raises(ConfigError) as cerr:
            validate(ZooSpec, {"train": "x", "families": section_in}, "zoo.yaml", "zoo entry")
        assert message in str(cerr.value), what
    with pytest.raises(ConfigError, match="judge:, families: or judging: required"):
        validate(ZooSpec, {"train": "x"}, "zoo.yaml", "zoo entry")
    assert FamiliesJudge(seed=0).seed == 0
    with pytest.raises(ValueError, match="has no families study"):
        families_for(FamiliesJudge(), PROBLEMS["redundant_gyros"])


def test_missing_seed_refused_before_any_work(tmp_path: Path) -> None:
    folder = _entry(tmp_path, [0, 1, 2], [0, 1], trials=2)
    before = _tree(folder)
    work = tmp_path / "w"
    res = runner.invoke(app, ["zoo", "evaluate", str(folder), "--work", str(work), "--quiet"])
    assert res.exit_code == 2, res.output
    text = " ".join(res.output.split())
    assert "training seed 2 of zoo.yaml has no model" in text
    assert "qkf zoo train fam" in text
    assert not work.exists() and _tree(folder) == before


def test_other_env_version_refused_before_any_work(tmp_path: Path) -> None:
    folder = _entry(tmp_path, [0, 1], [0, 1], trials=2)
    cfg = folder / "seed_1" / "config.yaml"
    cfg.write_text(cfg.read_text().replace("TransferAlignment-v1", "TransferAlignment-v2"))
    before = _tree(folder)
    work = tmp_path / "w"
    res = runner.invoke(app, ["zoo", "evaluate", str(folder), "--work", str(work), "--quiet"])
    assert res.exit_code == 2, res.output
    text = " ".join(res.output.split())
    assert "env: qkf/TransferAlignment-v2" in text and "qkf/TransferAlignment-v1" in text
    assert "seed 1" in text
    assert not work.exists() and _tree(folder) == before


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ({"baselines": ["kf-tuned", "no-such-method"]}, "no-such-method"),
        ({"overrides": ["run.bootstrap.level=0.9"]}, "run.bootstrap.level"),
        ({"overrides": ["scenario.duration_s=-1"]}, "duration_s"),
    ],
)
def test_bad_study_refused_before_any_work(
    tmp_path: Path, section: dict[str, object], message: str
) -> None:
    folder = _entry(tmp_path, [0], [0], families=["steady_random"], **section)
    work = tmp_path / "w"
    res = runner.invoke(app, ["zoo", "evaluate", str(folder), "--work", str(work), "--quiet"])
    assert res.exit_code == 2, res.output
    assert message in res.output
    assert not (work / "evaluation").exists() and not (work / "families").exists()


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_families_card_recomputed_from_trials(tmp_path: Path) -> None:
    folder = _entry(
        tmp_path, [0, 1], [0, 1], families=["steady_random", "ads_mismatch_random"],
        trials=3, seed=5, baselines=["kf", "kf-tuned"], overrides=SHORT,
    )  # fmt: skip
    work = tmp_path / "w"
    res = runner.invoke(
        app, ["zoo", "evaluate", str(folder), "--work", str(work), "--trials", "2", "--quiet"]
    )
    assert res.exit_code == 0, res.output
    # the shipped entry is not touched without --update-entry
    assert not (folder / "evaluation").exists() and not (folder / "card.md").exists()
    entry = load_entry(folder)
    shipped = entry.selected_seed()
    study = work / "families"
    assert (study / "families.md").is_file() and (study / "run.json").is_file()
    card = (work / "card.md").read_text()
    summary = _rows(work / "evaluation" / "zoo_families.csv")
    j = METRIC_COLUMNS.index(STATE_SETTLED)
    a, b = (read_trials_csv(study / f)["kf"] for f in ("steady_random", "ads_mismatch_random"))
    assert not np.array_equal(a, b)  # two families, two sets of trials
    for family in ("steady_random", "ads_mismatch_random"):
        values = read_trials_csv(study / family)
        assert set(values) == {"kf", "kf-tuned", "fam#0", "fam#1"}
        assert all(v.shape[0] == 2 for v in values.values())  # --trials replaced 3
        copied = work / "evaluation" / f"families_{family}_seed5_trials.csv"
        assert copied.read_bytes() == (study / family / "trials.csv").read_bytes()
        ref = values["kf-tuned"][:, j]
        scores = np.stack([ref / values["fam#0"][:, j], ref / values["fam#1"][:, j]])
        iqm = float(sps.trim_mean(scores.ravel(), 0.25))
        section = card.split(f"### {family}")[1].split("###")[0]
        shown = re.search(r"seeds × trials: ([0-9.]+) \[([0-9.]+), ([0-9.]+)\]", section)
        assert shown is not None, section
        assert float(shown[1]) == pytest.approx(iqm, abs=5e-4)
        assert float(shown[2]) <= float(shown[1]) <= float(shown[3])
        mine = [r for r in summary if r["scenario"] == family]
        row = next(r for r in mine if r["quantity"] == "iqm")
        assert float(row["value"]) == pytest.approx(iqm, rel=1e-5)
        # P(improve over kf): per trial, the share of seeds scoring above kf (ties: half)
        kf = ref / values["kf"][:, j]
        p = float(np.mean([np.mean((scores[:, k] > kf[k]) + 0.5 * (scores[:, k] == kf[k]))
                           for k in range(2)]))  # fmt: skip
        assert f"| kf | {p:.2f} |" in section
        row = next(r for r in mine if r["quantity"] == "p_improve" and r["versus"] == "kf")
        assert float(row["value"]) == pytest.approx(p)
        # the shipped seed ÷ kf-tuned, paired over the same trials
        rms = math.sqrt(float(np.mean(values[f"fam#{shipped}"][:, j] ** 2)))
        ratio = rms / math.sqrt(float(np.mean(ref**2)))
        row = next(r for r in mine if r["quantity"] == "ratio" and r["versus"] == "kf-tuned")
        assert row["policy"] == f"fam#{shipped}"
        assert float(row["value"]) == pytest.approx(ratio, rel=1e-5)
        pk = next(r for r in mine if r["quantity"] == "p_improve" and r["versus"] == "kf-tuned")
        assert f"| kf-tuned | {float(pk['value']):.2f} | {ratio:.3f} [" in section

    # the shift group is always judged, with the -mixed twins of the tuned baselines
    for shift in SHIFT_FAMILIES:
        assert set(read_trials_csv(study / shift)) == {"kf", "kf-tuned-mixed", "fam#0", "fam#1"}
        assert f"### {shift}" in card

    # an interrupted evaluation keeps its finished families: one family's folder gone (as if
    # the run stopped there), the next run into the same work folder reruns only that one
    kept = (study / "steady_random" / "trials.csv").read_bytes()
    redo = (study / "ads_mismatch_random" / "trials.csv").read_bytes()
    shutil.rmtree(study / "ads_mismatch_random")
    res = runner.invoke(
        app, ["zoo", "evaluate", str(folder), "--work", str(work), "--trials", "2", "--quiet"]
    )
    assert res.exit_code == 0, res.output
    assert "steady_random: finished earlier, kept" in res.output
    assert "ads_mismatch_random: finished earlier" not in res.output
    assert (study / "steady_random" / "trials.csv").read_bytes() == kept
    assert (study / "ads_mismatch_random" / "trials.csv").read_bytes() == redo

    # --update-entry: the entry's evaluation/ and card.md become the work folder's (the same
    # work folder: every family is kept, only the evaluation is written again)
    res = runner.invoke(
        app,
        ["zoo", "evaluate", str(folder), "--work", str(work), "--trials", "2", "--quiet",
         "--update-entry"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "ads_mismatch_random: finished earlier, kept" in res.output
    judged = sorted(p.name for p in (work / "evaluation").iterdir())
    assert sorted(p.name for p in (folder / "evaluation").iterdir()) == judged
    for name in judged:
        src = work / "evaluation" / name
        assert (folder / "evaluation" / name).read_bytes() == src.read_bytes()
    assert (folder / "card.md").read_bytes() == (work / "card.md").read_bytes()
