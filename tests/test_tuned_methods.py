"""The Optuna-tuned variants of the classical methods (docs/methods.md, "Tuned baselines"): each
prepares on a tiny budget and runs, evaluates its own settings first and never ends worse than
them, writes its cache and reads it back without a study, pickles, and is reproducible."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pytest

from qkf.transfer_alignment.config import Config, load_config
from qkf.transfer_alignment.judging import estimate_scores, pooled
from qkf.transfer_alignment.methods import tuned
from qkf.transfer_alignment.methods.base import validate_output
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.methods.tuned import (
    SCHEDULE,
    TUNED_METHODS,
    OptunaTuned,
    TunedSetting,
    TuningResult,
    cache_key,
    cache_path,
    tuning_budget,
)
from qkf.transfer_alignment.scenario import simulate

TINY = [
    "scenario.duration_s=600",
    # the jump (and the rotation sequence it starts) early enough to be inside the run
    "scenario.random_events.jump.t_s.low=300",
    "scenario.random_events.jump.t_s.high=350",
    "adaptive.tuned.trials=2",
    "adaptive.optuna.evaluations=3",
    # fewer compiled calls: covariance samples split the filter's blocks, and alarm-burst's
    # θ₀ tunes the oracle over κ × windows
    "run.nees_every_s=200",
    "adaptive.oracle.windows_s=[50, 100]",
]
# a bank of 11 filters, 10 VB iterations per epoch, and filters stepped one epoch at a time
# (a compiled call per epoch: seconds when other processes keep the cores busy)
HEAVY = {"imm-tuned", "vbakf-tuned", "fading-tuned", "covariance-matching-tuned"}


def tiny(*extra: str) -> Config:
    return load_config("thermal_snap_random", [*TINY, *extra])


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("QKF_CACHE_DIR", str(tmp_path))
    return tmp_path / "tuning"


@pytest.fixture
def studies(monkeypatch: pytest.MonkeyPatch) -> list[TuningResult]:
    """The results of the studies run from here on, in order."""
    seen: list[TuningResult] = []
    real = tuned.run_study

    def recording(tuner: OptunaTuned, cfg: Config) -> TuningResult:
        seen.append(real(tuner, cfg))
        return seen[-1]

    monkeypatch.setattr(tuned, "run_study", recording)
    return seen


def refuse_study(monkeypatch: pytest.MonkeyPatch) -> None:
    def fail(tuner: OptunaTuned, cfg: Config) -> TuningResult:
        raise AssertionError(f"{tuner.name}: a study ran although its result is cached")

    monkeypatch.setattr(tuned, "run_study", fail)


@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.slow) if n in HEAVY else n for n in TUNED_METHODS],
)
def test_variant_tunes_caches_and_runs(
    name: str,
    cache: Path,
    studies: list[TuningResult],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    cfg = tiny()
    method = TUNED_METHODS[name]
    prepared = method.prepare(cfg)
    (result,) = studies
    # θ₀ first, exactly as configured; three evaluations; the best never worse than θ₀
    assert len(result.history) == 3
    assert result.history[0] == (result.defaults, result.default_score)
    section = getattr(cfg.adaptive, method.section)
    for key, value in result.defaults.items():
        if key not in SCHEDULE:  # alarm-burst's schedule is the oracle's (tuned)
            assert value == getattr(section, key)
    assert result.score == min(score for _, score in result.history) <= result.default_score
    assert dict(prepared.settings) == result.settings
    # the cache: one file, read back by a second prepare without a study
    files = list(cache.glob(f"{name}-*.json"))
    assert files == [cache_path(name, cache_key(method, cfg))]
    refuse_study(monkeypatch)
    again = method.prepare(cfg)
    assert again.settings == prepared.settings and again.note == prepared.note
    # picklable, and it runs: on the tuning trials it scores what the study recorded, and so
    # do the defaults
    restored = pickle.loads(pickle.dumps(prepared))
    assert restored.settings == prepared.settings and restored.tuner.name == name
    data = simulate(cfg, cfg.adaptive.tuned.seed, 2)
    out = validate_output(restored(cfg, data), name, 2, data.n_epochs, covariance_epochs(cfg).size)
    assert pooled(estimate_scores(cfg, out.est, data), out.diverged) == result.score
    plain = TunedSetting(method, tuple(result.defaults.items()))(cfg, data)
    assert pooled(estimate_scores(cfg, plain.est, data), plain.diverged) == result.default_score
    note = out.notes[name]
    assert note.startswith(
        "tuned with Optuna: 3 evaluations × 2 trials of seed 1000003 on state_settled: "
    )
    assert f"(defaults {result.default_score:.4g})" in note


def test_same_seed_same_result_and_a_corrupt_cache_is_rewritten(
    cache: Path, studies: list[TuningResult], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = tiny()
    method = TUNED_METHODS["glr-tuned"]
    first = method.prepare(cfg)
    path = cache_path("glr-tuned", cache_key(method, cfg))
    path.write_text('{"key": ')  # half a file
    second = method.prepare(cfg)  # a study again (the file is unusable), same outcome
    assert len(studies) == 2 and studies[0] == studies[1]
    assert second.settings == first.settings
    assert json.loads(path.read_text())["settings"] == dict(first.settings)
    # another sampler seed explores other settings
    other = method.prepare(tiny("adaptive.optuna.sampler_seed=1"))
    assert [s for s, _ in studies[2].history[1:]] != [s for s, _ in studies[0].history[1:]]
    assert len(list(cache.glob("glr-tuned-*.json"))) == 2 and other.note


def key_of(name: str, *sets: str) -> Path:
    return cache_path(name, cache_key(TUNED_METHODS[name], tiny(*sets)))


@pytest.mark.parametrize(
    ("sets", "same"),
    [
        (["adaptive.qkf.alpha=0.5"], True),  # another method's settings
        (["run.trials=7", "run.seed=3"], True),  # the judged run
        (["adaptive.fading.softening=2"], False),  # its own settings
        (["adaptive.tuned.seed=1000004"], False),
        (["adaptive.tuned.metric=ma_urad_settled"], False),
        (["adaptive.optuna.evaluations=4"], False),
        (["run.settled_s=300"], False),  # the judged window
        (["scenario.ads.attitude_sigma_arcsec=5"], False),
        (["adaptive.actions.count=9"], False),
    ],
)
def test_cache_key(cache: Path, sets: list[str], same: bool) -> None:
    assert (key_of("fading-tuned", *sets) == key_of("fading-tuned")) is same
    assert key_of("fading-tuned").parent == cache


def test_alarm_burst_key_holds_the_oracle_settings(cache: Path) -> None:
    """θ₀ of alarm-burst-tuned is the oracle's schedule, so the oracle's settings are part of
    its key (and not of the others')."""
    sets = "adaptive.oracle.windows_s=[200]"
    assert key_of("alarm-burst-tuned", sets) != key_of("alarm-burst-tuned")
    assert key_of("glr-tuned", sets) == key_of("glr-tuned")


def test_budget() -> None:
    budget = tuning_budget(load_config("thermal_snap_random"))
    assert (budget.evaluations, budget.trials, budget.epochs) == (50, 16, 3600)
    assert budget.trial_epochs == 50 * 16 * 3600
    assert "50 evaluations × 16 trials × 3600 epochs" in str(budget)


def test_every_end_of_every_range_is_a_valid_setting() -> None:
    """A setting the search may propose must not be refused by the method's section, and the
    spaces name real settings."""
    cfg = load_config("thermal_snap_random")
    for method in TUNED_METHODS.values():
        fields = type(getattr(cfg.adaptive, method.section)).model_fields
        for param in method.space:
            if param.name in SCHEDULE:
                continue
            assert param.name in fields
            values = param.choices if param.kind == "choice" else (param.low, param.high)
            for value in values if param.kind != "action" else ():
                tuned.with_section(cfg, method.section, {param.name: value})
