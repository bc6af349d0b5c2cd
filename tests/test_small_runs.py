"""Small runs when the user asks for them (issue 32 item 5): a chosen subset of the baselines
(``--baselines``), and a method named twice runs once."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from conftest import ROOT
from typer.testing import CliRunner

from agents.zoo import load_entry
from agents.zoo.commands import case_baselines, families_run
from qkf.cli import app
from qkf.core.config import ConfigError
from qkf.core.method_specs import pick_baselines, spec_label

ENTRY = ROOT / "agents" / "zoo" / "ppo_mixed_v3"


def test_pick_baselines_keeps_the_order_and_names_the_choices() -> None:
    specs = ["kf", "kf-tuned", "best=policy:x.zip", "glr"]
    assert [spec_label(s) for s in specs] == ["kf", "kf-tuned", "best", "glr"]
    assert pick_baselines(specs, ["glr", "kf-tuned"]) == ["kf-tuned", "glr"]
    with pytest.raises(ConfigError, match=r"nosuch: not among the methods; choose from kf, kf-t"):
        pick_baselines(specs, ["glr", "nosuch"])
    with pytest.raises(ConfigError, match="none given"):
        pick_baselines(specs, [])


def test_a_zoo_entry_judged_on_a_subset_of_its_baselines() -> None:
    entry = load_entry(ENTRY)
    run = families_run(entry, 2, ["glr", "kf-tuned"])
    assert run.baselines == ("kf-tuned", "glr") and run.trials == 2
    with pytest.raises(ConfigError, match=r"zoo\.yaml: families: --baselines: oracle"):
        families_run(entry, 2, ["oracle"])
    for case in entry.spec.cases():
        assert case_baselines(entry, case, None) == list(case.baselines)


@pytest.mark.slow
def test_a_families_study_on_chosen_baselines_runs_a_repeated_method_once(
    tmp_path: Path,
) -> None:
    out = tmp_path / "fam"
    result = CliRunner().invoke(
        app,
        ["study", "families", "--families", "steady_random", "--trials", "2", "--quiet",
         "--baselines", "kf", "--methods", "kf,nominal=kf", "--set", "scenario.duration_s=600",
         "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    with (out / "study.csv").open() as fh:
        methods = [row["method"] for row in csv.DictReader(fh)]
    assert methods == ["kf", "nominal"]


def test_unknown_baselines_are_refused_before_any_work(tmp_path: Path) -> None:
    out = tmp_path / "fam"
    result = CliRunner().invoke(
        app,
        ["study", "families", "--families", "steady_random", "--trials", "2",
         "--baselines", "kf,nosuch", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 2, result.output
    assert "nosuch: not among the methods" in result.output
    assert not out.exists()


@pytest.mark.slow
def test_tunings_side_by_side_give_the_sequential_settings() -> None:
    """With worker processes the methods' tunings (kf-tuned's κ, the clock's schedule, an
    Optuna study) run side by side, one per process; each gives what it gives in sequence."""
    import numpy as np
    from conftest import cfg_with

    from qkf.transfer_alignment.benchmark import run_benchmark

    cfg = cfg_with("scenario.duration_s=500", "run.settled_s=300", "adaptive.tuned.trials=2",
                   "adaptive.optuna.evaluations=3", "run.chunk_trials=1")  # fmt: skip
    methods = "kf-tuned,clock,glr-tuned"
    here = run_benchmark(cfg, methods, trials=2, seed=7, progress=False)
    side = run_benchmark(cfg, methods, trials=2, seed=7, progress=False, workers=2)
    for a, b in zip(here.methods, side.methods, strict=True):
        assert a.name == b.name
        assert a.trial_values is not None and b.trial_values is not None
        np.testing.assert_array_equal(a.trial_values, b.trial_values)
        assert a.notes == b.notes  # the notes give the tuned values
