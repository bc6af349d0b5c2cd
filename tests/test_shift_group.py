"""Families that do not leak the change, and a shift group nothing trains or tunes on (issue 33,
item 3; docs/models.md "Scenario families", "Shift group")."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import yaml

from qkf.core.presets import preset_dir
from qkf.transfer_alignment.adaptive import TUNING_SEEDS
from qkf.transfer_alignment.config import Scenario, load_config
from qkf.transfer_alignment.methods.on_mixture import TRAINING_MIXTURE, mixture_config
from qkf.transfer_alignment.problem import FAMILIES, SHIFT_FAMILIES
from qkf.transfer_alignment.scenario import draw_events, family_names, trial_streams
from qkf.transfer_alignment.settled import opening_end_s

ROOT = Path(__file__).resolve().parents[1]
DRAWS = 300


def _drawn(name: str) -> list[Scenario]:
    sc = load_config(name).scenario
    return [draw_events(sc, trial_streams(5_500_000, i)["events"]) for i in range(DRAWS)]


def test_rotations_come_without_a_change() -> None:
    for sc in _drawn("rotation_only_random"):
        assert not sc.calibration_jumps
        starts = sorted({m.start_s for m in sc.maneuvers})
        later = [t for t in starts if t >= 900.0]
        seqs = [later[0], *[t for a, t in itertools.pairwise(later) if t - a > 200.0]]
        assert len(seqs) == 2 and seqs[1] - seqs[0] >= 600.0 - 1e-9


def test_quiet_changes_have_no_rotation_within_300_s() -> None:
    for sc in _drawn("quiet_snap_random"):
        (jump,) = sc.calibration_jumps
        for m in sc.maneuvers:
            assert m.start_s + m.duration_s <= jump.t_s - 300.0 or m.start_s >= jump.t_s + 300.0
        later = min(m.start_s for m in sc.maneuvers if m.start_s > jump.t_s)
        assert len(sc.maneuvers) == 6 and 300.0 <= later - jump.t_s <= 900.0
        assert opening_end_s(sc.maneuvers) <= 450.0 + 1e-9


def test_threshold_jump_sizes_span_zero_to_large() -> None:
    sizes = np.array([np.abs(sc.calibration_jumps[0].misalignment_urad) for sc in
                      _drawn("threshold_snap_random")])  # fmt: skip
    assert sizes.min() < 5.0 and sizes.max() > 110.0 and sizes.max() <= 120.0


def test_mixture_trains_on_the_new_families_and_no_shift_family() -> None:
    mixture = load_config(TRAINING_MIXTURE)
    names = family_names(mixture)
    assert set(names) == set(FAMILIES) - {TRAINING_MIXTURE}
    assert not set(names) & set(SHIFT_FAMILIES)
    # no component draws a shift family's events either, whatever its name
    comps = [c.events for c in mixture.scenario.random_events.mixture]  # type: ignore[union-attr]
    for shift in SHIFT_FAMILIES:
        sc = load_config(shift).scenario
        assert sc.random_events is not None
        assert (
            sc.random_events.model_dump(exclude={"mixture"}) not in [c.model_dump() for c in comps]
            or sc.truth_prior_scale != mixture.scenario.truth_prior_scale
        )


@pytest.mark.parametrize("shift", SHIFT_FAMILIES)
def test_shift_families_change_one_law(shift: str) -> None:
    cfg = load_config(shift)
    assert cfg.scenario.random_events is not None
    # a "-mixed" tuning of a shift family's baselines runs on the training mixture, never on it
    tuned = mixture_config(cfg)
    assert tuned.scenario == load_config(TRAINING_MIXTURE).scenario


def test_no_training_or_tuning_config_names_a_shift_family() -> None:
    """Every training config (configs/training/*.yaml) and study preset: none trains on, or
    tunes on, a shift family; the zoo's entries train on the judging-free seed ranges."""
    texts = {p: p.read_text() for p in (ROOT / "configs" / "training").glob("*.yaml")}
    texts |= {
        p: p.read_text() for p in (preset_dir("transfer_alignment") / "studies").glob("*.yaml")
    }
    for path, text in texts.items():
        for shift in SHIFT_FAMILIES:
            if "studies" in path.parts and path.stem == "families":
                continue  # the families study judges them (on request), it does not tune on them
            assert shift not in text, f"{path} names the shift family {shift}"
    study = yaml.safe_load(
        (preset_dir("transfer_alignment") / "studies" / "families.yaml").read_text()
    )
    assert not set(study["families"]) & set(SHIFT_FAMILIES)  # judged only with --shift
    assert list(study.get("shift_families", [])) == list(SHIFT_FAMILIES)
    assert TUNING_SEEDS[0] > 9000  # the judged seed of the families study is not a tuning seed


def test_shift_study_runs_the_mixed_twins_only(tmp_path: Path) -> None:
    """qkf study families --shift: a shift family runs each tuned baseline as its -mixed
    variant (and no oracle), and its ratios are to kf-tuned-mixed."""
    import csv

    from typer.testing import CliRunner

    from qkf.cli import app

    out = tmp_path / "out"
    res = CliRunner().invoke(
        app,
        ["study", "families", "--families", "steady_random,shift_prior_random", "--trials", "3",
         "--seed", "5500000", "--quiet", "--out", str(out), "--baselines", "kf,kf-tuned,oracle",
         "--set", "scenario.duration_s=1200", "--set", "adaptive.tuned.trials=2",
         "--set", "run.bootstrap.resamples=200"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    with (out / "families.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    methods = {fam: {r["method"] for r in rows if r["family"] == fam} for fam in
               ("steady_random", "shift_prior_random")}  # fmt: skip
    assert methods["steady_random"] == {"kf", "kf-tuned", "oracle"}
    assert methods["shift_prior_random"] == {"kf", "kf-tuned-mixed"}
    assert {r["reference"] for r in rows if r["family"] == "shift_prior_random"} == {
        "kf-tuned-mixed"
    }
    md = (out / "families.md").read_text()
    assert "A shift family: nothing tunes on it" in md


def test_shift_group_is_judged_on_request_only() -> None:
    from qkf.transfer_alignment.study import load_study

    study, _ = load_study("families")
    assert not study.shift_families
    study, _ = load_study("families", shift=True)
    assert list(study.shift_families) == list(SHIFT_FAMILIES)
