"""One settings path for methods (docs/architecture.md, "Recipe: add a method"): each method
reads its own section of ``adaptive``, validated by its own model, before any work.

The user's method of tests/user_method_example.py takes ``adaptive.mine.gain`` as its constant
κ, so ``kappa.csv`` shows whether the setting reached it: from YAML and from ``--set``, in this
process, in a process pool and in Ray workers, and again from the manifest. A section no method
of the run reads, a bad value and a bad declaration are refused with the field named, exit 2,
nothing written.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core.config import ConfigError, PositiveFloat, StrictModel
from qkf.transfer_alignment.adaptive import AdaptiveConfig, AlarmBurstConfig, ImmConfig
from qkf.transfer_alignment.alarms import NIS_ALARM, QUIET_S, change_clock
from qkf.transfer_alignment.benchmark import run_benchmark
from qkf.transfer_alignment.config import builtin_section, load_config
from qkf.transfer_alignment.methods import (
    METHODS,
    MethodSpecError,
    NamedMethod,
    method_settings,
    resolve_method,
    resolve_method_settings,
    uses_settings,
)
from qkf.transfer_alignment.methods.alarm_burst import AlarmBurstSchedule, run_alarm_burst
from qkf.transfer_alignment.methods.base import MethodOutput, declared_settings, settings_of
from qkf.transfer_alignment.methods.oracle import OracleSchedule
from qkf.transfer_alignment.scenario import ScenarioData, simulate
from tests.conftest import ROOT, cfg_with
from tests.user_method_example import MineSettings, run_mine

runner = CliRunner()
MINE = "mine=tests.user_method_example:run_mine"
RUN = ("paper", "--methods", f"kf,{MINE}", "--trials", "4")
SHORT = ("scenario.duration_s=60", "run.chunk_trials=2")  # 4 trials: two chunks, two workers
GAIN_2 = [a for s in (*SHORT, "adaptive.mine.gain=2") for a in ("--set", s)]


@pytest.fixture
def importable(monkeypatch: pytest.MonkeyPatch) -> None:
    """The checkout on every worker's import path, as a user arranges for their own module:
    spawned pool workers take this process's path, Ray workers the environment's."""
    monkeypatch.syspath_prepend(str(ROOT))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))


def _bench(*args: str) -> tuple[int, str]:
    result = runner.invoke(app, ["bench", *args, "--quiet"])
    return result.exit_code, result.output


def _kappa(folder: Path, method: str) -> np.ndarray:
    with (folder / "kappa.csv").open() as f:
        return np.array([float(r["kappa"]) for r in csv.DictReader(f) if r["method"] == method])


def _config(folder: Path) -> dict[str, Any]:
    config: dict[str, Any] = json.loads((folder / "run.json").read_text())["config"]
    return config


# ---- a user's method with one setting, end to end ------------------------------------------


def test_setting_from_yaml_reaches_the_method_and_the_manifest(
    tmp_path: Path, importable: None
) -> None:
    cfg = tmp_path / "mine.yaml"
    cfg.write_text("scenario:\n  duration_s: 60\nadaptive:\n  mine:\n    gain: 2.5\n")
    out = tmp_path / "out"
    code, text = _bench(str(cfg), "--methods", f"kf,{MINE}", "--trials", "3", "--out", str(out))
    assert code == 0, text
    kappa = _kappa(out, "mine")
    assert kappa.size > 0 and np.all(kappa == 2.5)
    assert _config(out)["adaptive"]["mine"] == {"gain": 2.5}
    # the manifest reruns it with the same setting: the same files
    again = tmp_path / "again"
    code, text = _bench("--from-manifest", str(out / "run.json"), "--out", str(again))
    assert code == 0, text
    for name in ("kappa.csv", "rms.csv", "trials.csv"):
        assert (again / name).read_bytes() == (out / name).read_bytes(), name


@pytest.fixture(scope="module")
def inline(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``--set adaptive.mine.gain=2``, run in this process (the reference of the backends)."""
    out = tmp_path_factory.mktemp("inline") / "out"
    code, text = _bench(
        "paper", "--methods", f"kf,{MINE}", "--trials", "4", *GAIN_2, "--out", str(out)
    )
    assert code == 0, text
    return out


def test_setting_from_set_reaches_the_method(inline: Path) -> None:
    kappa = _kappa(inline, "mine")
    assert kappa.size > 0 and np.all(kappa == 2.0)
    assert _config(inline)["adaptive"]["mine"] == {"gain": 2.0}


@pytest.mark.parametrize("backend", [("--workers", "2"), ("--backend", "ray")], ids=str)
def test_every_backend_passes_the_setting_on(
    inline: Path,
    tmp_path: Path,
    importable: None,
    backend: tuple[str, str],
    request: pytest.FixtureRequest,
) -> None:
    """The config, user section included, travels to pool and Ray workers by pickling, and they
    import the method (and its model) by name: the same files, bit for bit."""
    if backend[0] == "--backend":
        request.getfixturevalue("ray_cluster")  # its workers import from the checkout
    out = tmp_path / "out"
    code, text = _bench(
        "paper", "--methods", f"kf,{MINE}", "--trials", "4", *GAIN_2, *backend, "--out", str(out)
    )
    assert code == 0, text
    assert _config(out) == _config(inline)
    for name in ("kappa.csv", "rms.csv", "trials.csv"):
        assert (out / name).read_bytes() == (inline / name).read_bytes(), name


def test_defaults_are_written_into_the_resolved_config() -> None:
    res = run_benchmark(cfg_with(*SHORT), [MINE], trials=1, seed=0, progress=False)
    assert res.config.adaptive.model_extra == {"mine": {"gain": 1.0}}
    assert res.methods[0].kappa is not None and np.all(res.methods[0].kappa == 1.0)
    # a run of built-in methods only keeps the config it was given, object and all
    cfg = cfg_with(*SHORT)
    assert resolve_method_settings(cfg, [resolve_method("kf"), resolve_method("imm")]) is cfg


# ---- refusals: exit 2, the field named, nothing written -------------------------------------


@pytest.mark.parametrize(
    ("sets", "methods", "message"),
    [
        (["adaptive.mine.gain=-1"], f"kf,{MINE}", "adaptive.mine.gain: Input should be greater"),
        (["adaptive.mine.gian=2"], f"kf,{MINE}", "adaptive.mine.gian: unknown key"),
        (["adaptive.mine.gain=2"], "kf", "adaptive.mine: unknown key (no method of this run"),
        (["adaptive.mnie.gain=2"], f"kf,{MINE}", "adaptive.mnie: unknown key"),
        (["adaptive.mine.gain=true"], f"kf,{MINE}", "adaptive.mine.gain: Input should be a num"),
        (["adaptive.mine=3"], f"kf,{MINE}", "adaptive.mine: Input should be a valid dictionary"),
        (["adaptive.mine.gain=.nan"], f"kf,{MINE}", "adaptive.mine.gain: Input should be a fin"),
    ],
)
def test_bad_settings_are_refused_before_any_work(
    tmp_path: Path, importable: None, sets: list[str], methods: str, message: str
) -> None:
    out = tmp_path / "out"
    args = [a for s in (*SHORT, *sets) for a in ("--set", s)]
    code, text = _bench("paper", "--methods", methods, "--trials", "2", *args, "--out", str(out))
    assert code == 2, text
    assert message in " ".join(text.split())
    assert "Traceback" not in text and not out.exists()


def test_an_unclaimed_section_in_a_file_is_refused_with_the_file_named(tmp_path: Path) -> None:
    path = tmp_path / "typo.yaml"
    path.write_text("adaptive:\n  mnie:\n    gain: 2\n")
    cfg = load_config(path)  # held as written: the methods are not known yet
    with pytest.raises(ConfigError, match=rf"{path}: adaptive\.mnie: unknown key"):
        resolve_method_settings(cfg, [resolve_method(MINE)], str(path))
    path.write_text("adaptive:\n  mine:\n    gain: 0\n")
    with pytest.raises(ConfigError, match=rf"{path}: adaptive\.mine\.gain: Input should be"):
        resolve_method_settings(load_config(path), [resolve_method(MINE)], str(path))


# ---- declarations ------------------------------------------------------------------------------


class OtherSettings(StrictModel):
    gain: PositiveFloat = 3.0


@uses_settings("mine", OtherSettings)
def run_other(cfg: object, data: ScenarioData) -> MethodOutput:  # never run
    raise AssertionError


@uses_settings("imm", OtherSettings)
def run_not_imm(cfg: object, data: ScenarioData) -> MethodOutput:  # never run
    raise AssertionError


def test_declarations_are_checked() -> None:
    assert declared_settings(run_mine) == ("mine", MineSettings)
    assert declared_settings(METHODS["kf"]) is None
    with pytest.raises(ValueError, match="identifier"):
        uses_settings("my.section", MineSettings)
    with pytest.raises(ValueError, match="identifier"):
        uses_settings("_private", MineSettings)
    with pytest.raises(ValueError, match="StrictModel subclass"):
        uses_settings("mine", dict)  # type: ignore[arg-type]
    cfg = cfg_with(*SHORT)
    # two methods, one section: one model only
    both = [resolve_method(MINE), NamedMethod("other", run_other)]
    with pytest.raises(ConfigError, match=r"adaptive\.mine: read by method 'mine' as Mine"):
        resolve_method_settings(cfg, both)
    # a built-in section keeps its own model
    with pytest.raises(ConfigError, match=r"adaptive\.imm: method 'x' reads it as Other"):
        resolve_method_settings(cfg, [NamedMethod("x", run_not_imm)])

    class Broken:
        settings_section = "fine"
        settings = dict

        def __call__(self, cfg: object, data: object) -> None: ...

    with pytest.raises(MethodSpecError, match="StrictModel subclass"):
        resolve_method_settings(cfg, [NamedMethod("broken", Broken())])  # type: ignore[arg-type]


def test_every_builtin_section_is_declared_by_its_method() -> None:
    """Each section of AdaptiveConfig but the action set is one built-in method's, declared
    with the section's own model; only ``adaptive.optuna`` is shared, by the ``-tuned``
    variants (their common tuning budget)."""
    declared: dict[str, str] = {}
    for name in METHODS.names():
        found = declared_settings(METHODS[name])
        if name.endswith("-mixed"):  # tuned on the training mixture: its base's declaration
            assert found == declared_settings(METHODS[name.removesuffix("-mixed")]), name
            continue
        if found is None:
            continue
        section, model = found
        assert builtin_section(section) is model, name
        if section == "optuna":
            assert name.endswith("-tuned"), name
        else:
            assert section not in declared, f"{section}: {declared.get(section)} and {name}"
        declared[section] = name
    assert sorted(declared) == sorted(set(AdaptiveConfig.model_fields) - {"actions"})


def test_method_settings_reads_an_unresolved_config_too() -> None:
    """A method called directly, outside a benchmark, still gets checked settings."""
    assert method_settings(cfg_with(), "mine", MineSettings) == MineSettings()
    assert method_settings(cfg_with("adaptive.mine.gain=4"), "mine", MineSettings).gain == 4.0
    with pytest.raises(ConfigError, match=r"adaptive\.mine\.gain: Input should be greater"):
        method_settings(cfg_with("adaptive.mine.gain=0"), "mine", MineSettings)
    assert method_settings(cfg_with(), "imm", ImmConfig) == ImmConfig()
    with pytest.raises(
        ConfigError, match=r"adaptive\.imm: the built-in section of type ImmConfig cannot"
    ):
        method_settings(cfg_with(), "imm", MineSettings)


# ---- the alarm settings, shared by alarm-burst and the environment ---------------------------


def test_change_clock_takes_the_configured_alarm_settings() -> None:
    assert (NIS_ALARM, QUIET_S) == (AlarmBurstConfig().nis_alarm, AlarmBurstConfig().quiet_s)
    cfg = cfg_with("adaptive.alarm_burst.nis_alarm=7", "adaptive.alarm_burst.quiet_s=100")
    clock = change_clock(settings_of(run_alarm_burst, cfg, AlarmBurstConfig), 3)
    assert (clock.nis_alarm, clock.quiet_s) == (7.0, 100.0)
    np.testing.assert_array_equal(clock.alarms(np.array([6.9, 7.0, 7.1])), [False, False, True])
    default = change_clock(settings_of(run_alarm_burst, cfg_with(), AlarmBurstConfig), 1)
    assert (default.nis_alarm, default.quiet_s) == (NIS_ALARM, QUIET_S)


def test_alarm_burst_alarms_at_the_configured_threshold() -> None:
    """No threshold is ever exceeded: κ_base throughout; every period exceeds a tiny one: the
    burst opens at the first period (quiet since the start) and runs its window."""
    schedule = AlarmBurstSchedule(OracleSchedule(base=2.5, after=100.0, window_s=50.0))
    cfg = cfg_with("scenario.duration_s=200", "adaptive.alarm_burst.nis_alarm=1e9")
    data = simulate(cfg, 0, 2)
    never = schedule(cfg, data).kappa
    assert never is not None and np.all(never == 2.5)
    tiny = cfg_with("scenario.duration_s=200", "adaptive.alarm_burst.nis_alarm=1e-9")
    always = schedule(tiny, data).kappa
    assert always is not None
    # the alarm of period 0 starts a change (quiet since the start); κ follows the period
    # that alarmed, so periods 1–5 (age 0 … 40 s < W = 50 s) run κ_after, the rest κ_base
    np.testing.assert_array_equal(always[:, :10], 2.5)
    np.testing.assert_array_equal(always[:, 10:60], 100.0)
    np.testing.assert_array_equal(always[:, 60:], 2.5)
