"""Numbers must be numbers, and a run must fit (issue 18).

Every numeric field of every config model refuses ``true``/``false`` and strings (pydantic's lax
mode would run ``duration_s: true`` as a 1-second scenario), through every command, with exit 2,
the file and the field named and nothing written; an int still fills a float field and a YAML
list a tuple. A run whose trials × epochs (or one chunk's) exceed the documented limits is
refused on load, before any work.
"""

from __future__ import annotations

import types
import typing
from pathlib import Path
from typing import Annotated, Any, Union

import pytest
import yaml
from pydantic import ValidationError
from typer.testing import CliRunner

import agents.config
import agents.zoo.entry
import qkf.alignment.config as alignment
import qkf.core.actions
import qkf.redundant_gyros.config as gyros
import qkf.sca_fusion.config as fusion
import qkf.transfer_alignment.claims
import qkf.transfer_alignment.config as ta
import qkf.transfer_alignment.study
from qkf.cli import app
from qkf.core.config import ConfigError, StrictModel, load_yaml
from qkf.redundant_gyros import load_config as load_gyros
from tests.conftest import ALIGNMENT_CONFIGS

runner = CliRunner()

ALIGNMENT = yaml.safe_load((ALIGNMENT_CONFIGS / "alignment_three_sensors.yaml").read_text())
"""A complete alignment config (its schema has required keys), to spoil one value of."""


def _alignment_with(path: list[str | int], value: Any) -> dict[str, Any]:
    data: Any = yaml.safe_load(yaml.safe_dump(ALIGNMENT))  # a deep copy
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return typing.cast(dict[str, Any], data)


TRAIN = {"agent": "tabular", "scenario": "thermal_snap", "reward": "oracle"}

NUMBER = "Input should be a number, not"
INTEGER = "Input should be an integer, not"

# case: (command, config as a mapping, the line the command prints after the file name)
NOT_NUMBERS: dict[str, tuple[list[str], dict[str, Any], str]] = {
    "bench, bool": (
        ["bench"],
        {"scenario": {"duration_s": True}},
        f"scenario.duration_s: {NUMBER} true",
    ),
    "bench, string": (
        ["bench"],
        {"scenario": {"duration_s": "600"}},
        f"scenario.duration_s: {NUMBER} the string '600' (write it without quotes)",
    ),
    "bench, bool in a tuple": (
        ["bench"],
        {"scenario": {"truth": {"bias_degph": [1.0, False, 0.6]}}},
        f"scenario.truth.bias_degph.1: {NUMBER} false",
    ),
    "bench, string for an int": (
        ["bench"],
        {"run": {"trials": "20"}},
        f"run.trials: {INTEGER} the string '20' (write it without quotes)",
    ),
    "gyros bench, bool": (
        ["gyros", "bench"],
        {"bench": {"duration_s": True}},
        f"bench.duration_s: {NUMBER} true",
    ),
    "gyros bench, string": (
        ["gyros", "bench"],
        {"scenario": {"dt_s": "0.1"}},
        f"scenario.dt_s: {NUMBER} the string '0.1'",
    ),
    "fuse, bool": (
        ["fuse"],
        {"simulation": {"duration_s": True}},
        f"simulation.duration_s: {NUMBER} true",
    ),
    "fuse, string": (
        ["fuse"],
        {"estimator": {"iteration_count": "15"}},
        f"estimator.iteration_count: {INTEGER} the string '15'",
    ),
    "align, bool": (
        ["align"],
        _alignment_with(["solver", "max_iterations"], True),
        f"solver.max_iterations: {INTEGER} true",
    ),
    "align, string": (
        ["align"],
        _alignment_with(["sensors", 1, "sigma_arcsec"], "five"),
        f"sensors.1.sigma_arcsec: {NUMBER} the string 'five'",
    ),
    "train, bool": (["train"], {**TRAIN, "period_s": True}, f"period_s: {NUMBER} true"),
    "train, string": (["train"], {**TRAIN, "n_envs": "4"}, f"n_envs: {INTEGER} the string '4'"),
}
QUIET = {"bench", "gyros", "fuse", "train"}
"""Commands with a progress bar (and so a --quiet option)."""


def _write(path: Path, data: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _refused(args: list[str], cfg: Path, out: Path, *needles: str, file: bool = True) -> str:
    """Run the command; it must exit 2 with one error (naming the file: ``file``), before
    writing anything."""
    quiet = ["--quiet"] if args[0] in QUIET else []
    res = runner.invoke(app, [*args, str(cfg), "--out", str(out), *quiet])
    assert res.exit_code == 2, res.output
    flat = " ".join(res.output.split())
    assert "Traceback" not in flat and flat.count("error:") == 1, res.output
    for needle in ([str(cfg)] if file else []) + list(needles):
        assert needle in flat, res.output
    assert not out.exists()
    assert list(cfg.parent.iterdir()) == [cfg]
    return flat


@pytest.mark.parametrize("case", list(NOT_NUMBERS))
def test_a_bool_or_a_string_in_a_numeric_field_is_refused(case: str, tmp_path: Path) -> None:
    command, data, line = NOT_NUMBERS[case]
    cfg = _write(tmp_path / "bad.yaml", data)
    _refused(command, cfg, tmp_path / "out", f"{cfg}: {line}")


def test_a_quoted_number_set_on_the_command_line_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "out"
    res = runner.invoke(
        app, ["bench", "paper", "--set", 'scenario.duration_s="600"', "--out", str(out)]
    )
    assert res.exit_code == 2, res.output
    flat = " ".join(res.output.split())
    assert (
        "scenario.duration_s: Input should be a number, not the string '600' "
        "(write it without quotes)" in flat
    ), res.output
    assert not out.exists()


def test_the_message_is_one_line_per_field() -> None:
    with pytest.raises(ConfigError) as err:
        ta.load_config("paper", ["scenario.duration_s=true", "filter.quadrature_nodes=abc"])
    lines = str(err.value).splitlines()
    assert lines[0] == "invalid configuration"
    assert lines[1].endswith("scenario.duration_s: Input should be a number, not true")
    assert lines[2].endswith(
        "filter.quadrature_nodes: Input should be an integer, not the string 'abc'"
    )


# ---- what stays accepted ----------------------------------------------------------------------


def test_ints_fill_float_fields_and_lists_fill_tuples(tmp_path: Path) -> None:
    cfg = ta.load_config(
        _write(
            tmp_path / "ta.yaml",
            {"scenario": {"duration_s": 600, "truth": {"bias_degph": [1, 2, 3]}}},
        )
    )
    assert cfg.scenario.duration_s == 600.0 and isinstance(cfg.scenario.duration_s, float)
    assert cfg.scenario.truth.bias_degph == (1.0, 2.0, 3.0)
    assert all(isinstance(v, float) for v in cfg.scenario.truth.bias_degph)
    assert ta.load_config("paper", ["scenario.duration_s=600"]).scenario.duration_s == 600.0

    g = load_gyros(_write(tmp_path / "g.yaml", {"bench": {"duration_s": 45}}))
    assert isinstance(g.bench.duration_s, float)
    f = fusion.load_config(_write(tmp_path / "f.yaml", {"simulation": {"duration_s": 900}}))
    assert isinstance(f.simulation.duration_s, float)
    a = alignment.load_config(
        _write(tmp_path / "a.yaml", _alignment_with(["sensors", 0, "sigma_arcsec"], 7))
    )
    assert a.sensors[0].sigma_arcsec == 7.0 and isinstance(a.sensors[0].sigma_arcsec, float)
    t = agents.config.load_train_config(
        _write(tmp_path / "t.yaml", {**TRAIN, "period_s": 20}), check_scenario=False
    )
    assert t.period_s == 20.0 and isinstance(t.period_s, float)


def test_non_numeric_fields_are_unaffected(tmp_path: Path) -> None:
    cfg = ta.load_config(
        "paper",
        [
            "scenario.randomize_truth=true",
            "filter.rate_noise_correlation=false",
            "sweep={key: scenario.dt_s, values: [true, '2', 3]}",  # Any: the sweep's business
        ],
    )
    assert cfg.scenario.randomize_truth is True
    assert cfg.filter.rate_noise_correlation is False
    assert cfg.sweep is not None and cfg.sweep.values == [True, "2", 3]
    t = agents.config.load_train_config(
        _write(tmp_path / "t.yaml", {**TRAIN, "tabular": {"alpha": 0.2}}), check_scenario=False
    )
    assert t.tabular == {"alpha": 0.2}


def test_exponents_without_a_dot_are_numbers(tmp_path: Path) -> None:
    # PyYAML (YAML 1.1) reads 1e5 as the string '1e5', which a numeric field now refuses
    assert load_yaml("a: 1e5\nb: -2E-3\nc: '1e5'\nd: 1.0e-3\ne: 7") == {
        "a": 100000.0,
        "b": -0.002,
        "c": "1e5",
        "d": 0.001,
        "e": 7,
    }
    cfg = ta.load_config(_write_text(tmp_path / "c.yaml", "filter:\n  qp0: 1e-20\n"))
    assert cfg.filter.qp0 == 1e-20
    assert ta.load_config("paper", ["filter.qp0=1e-16"]).filter.qp0 == 1e-16


def _write_text(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# ---- every model, every numeric field ---------------------------------------------------------

MODULES = (
    ta,
    gyros,
    fusion,
    alignment,
    agents.config,
    agents.zoo.entry,
    qkf.core.actions,
    qkf.transfer_alignment.study,
    qkf.transfer_alignment.claims,
)  # imported for their models: StrictModel.__subclasses__ then sees them all


def _models() -> list[type[StrictModel]]:
    seen: list[type[StrictModel]] = []
    todo = list(StrictModel.__subclasses__())
    while todo:
        cls = todo.pop()
        if cls not in seen:
            seen.append(cls)
            todo += cls.__subclasses__()
    return sorted(seen, key=lambda c: f"{c.__module__}.{c.__qualname__}")


def _is_number(annotation: Any) -> bool:
    """A field that takes a bare number: int or float, possibly Optional, a union, Annotated."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return _is_number(typing.get_args(annotation)[0])
    if origin in (Union, types.UnionType):
        return any(_is_number(a) for a in typing.get_args(annotation))
    return annotation in (int, float)


def _fields(kind: str) -> list[tuple[type[StrictModel], str]]:
    return [
        (cls, name)
        for cls in _models()
        for name, field in cls.model_fields.items()
        if (kind == "number" and _is_number(field.annotation))
        or (kind == "bool" and field.annotation is bool)
    ]


def test_every_problem_has_models_with_numbers() -> None:
    modules = {cls.__module__ for cls, _ in _fields("number")}
    assert {m.__name__ for m in (ta, gyros, fusion, alignment, agents.config)} <= modules


@pytest.mark.parametrize("value", [True, False, "1", "abc"])
def test_every_numeric_field_of_every_model_refuses_it(value: object) -> None:
    fields = _fields("number")
    assert len(fields) > 100
    missed = []
    for cls, name in fields:
        try:
            cls.model_validate({name: value})
        except ValidationError as exc:
            mine = [e for e in exc.errors() if e["loc"][:1] == (name,)]
            if mine and all("Input should be" in e["msg"] for e in mine):
                if any(", not " in e["msg"] for e in mine):
                    continue
        missed.append(f"{cls.__qualname__}.{name}")
    assert not missed, f"{value!r} not refused as a non-number by: {', '.join(missed)}"


def test_every_bool_field_still_takes_true_and_false() -> None:
    fields = _fields("bool")
    assert len(fields) > 10
    for cls, name in fields:
        for value in (True, False):
            try:
                cls.model_validate({name: value})
            except ValidationError as exc:  # other fields may be required: not this one
                assert not [e for e in exc.errors() if e["loc"][:1] == (name,)], (cls, name)


# ---- workload limits --------------------------------------------------------------------------


def test_a_run_too_big_for_its_trials_is_refused_before_anything_is_written(
    tmp_path: Path,
) -> None:
    cfg = _write(
        tmp_path / "big.yaml", {"scenario": {"duration_s": 100_000}, "run": {"trials": 10**7}}
    )
    flat = _refused(
        ["bench"],
        cfg,
        tmp_path / "out",
        "run.trials × epochs (scenario.duration_s / scenario.dt_s) = "
        "10,000,000 × 100,000 = 1e+12 trial-epochs; at most 1e+09",
    )
    assert "(top level)" not in flat


def test_a_chunk_too_big_is_refused_naming_chunk_trials(tmp_path: Path) -> None:
    cfg = _write(
        tmp_path / "chunk.yaml",
        {"scenario": {"duration_s": 1_000_000}, "run": {"trials": 100, "chunk_trials": 64}},
    )
    _refused(
        ["bench"],
        cfg,
        tmp_path / "out",
        "run.chunk_trials × epochs",
        "64 × 1,000,000 = 6.4e+07 trial-epochs in one chunk; at most 2e+07",
        "set run.chunk_trials to 20 or less",
        file=False,  # checked by the command (check_workload), which knows no file name
    )
    # only a benchmark holds chunks: the file loads (an environment may use its scenario), and
    # the suggested chunk size is accepted
    ta.check_workload(ta.load_config(cfg, ["run.chunk_trials=20"]))
    with pytest.raises(ConfigError, match=r"set run\.chunk_trials to 20 or less"):
        ta.check_workload(ta.load_config(cfg))


def test_workload_limits_accept_normal_runs() -> None:
    paper = ta.load_config("paper")
    ta.check_workload(paper)
    day = ta.load_config("paper", ["scenario.duration_s=86400", "run.chunk_trials=64"])
    ta.check_workload(day, 1000)  # 1,000 trials of a day: 8.6e7 trial-epochs
    with pytest.raises(ConfigError, match=r"--trials × epochs .* 1\.73e\+09 trial-epochs"):
        ta.check_workload(day, 20_000)
    # a chunk never holds more than the run's trials
    long = ta.load_config("paper", ["scenario.duration_s=1000000", "run.trials=20"])
    ta.check_workload(long)
    with pytest.raises(ConfigError, match=r"min\(run.chunk_trials, --trials\)"):
        ta.check_workload(long, 30)
    assert ta.MAX_CHUNK_TRIAL_EPOCHS >= ta.MAX_EPOCHS  # a chunk of 1 always fits


def test_gyros_bench_too_big_is_refused(tmp_path: Path) -> None:
    cfg = _write(tmp_path / "big.yaml", {"bench": {"trials": 10**7, "duration_s": 10_000.0}})
    _refused(
        ["gyros", "bench"],
        cfg,
        tmp_path / "out",
        "bench.trials × epochs (bench.duration_s / scenario.dt_s) × fault groups",
        "10,000,000 × 100,000 × 24 = 2.4e+13 trial-epochs; at most 1e+10",
    )


def test_gyros_workload_limits() -> None:
    preset = load_gyros("five_gyros")
    gyros.check_workload(preset)
    gyros.check_workload(preset, 10_000)
    with pytest.raises(ConfigError, match=r"--trials × epochs"):
        gyros.check_workload(preset, 10**7)
    # the UKF accuracy run of the bench simulates all its trials over the scenario at once;
    # other commands may still use a long scenario
    long = load_gyros("five_gyros", ["scenario.duration_s=1000000"])
    with pytest.raises(ConfigError, match=r"set bench.ukf_trials to 2 or less"):
        gyros.check_workload(long)
    fewer = load_gyros("five_gyros", ["scenario.duration_s=1000000", "bench.ukf_trials=2"])
    gyros.check_workload(fewer)
    with pytest.raises(ConfigError, match=r"bench.duration_s / scenario.dt_s\) = 1e\+08"):
        load_gyros("five_gyros", ["bench.duration_s=1e7"])


def test_overrides_can_fix_a_file_refused_on_its_own_but_not_hide_its_errors(
    tmp_path: Path,
) -> None:
    cfg = _write(tmp_path / "c.yaml", {"scenario": {"duration_s": True}})
    with pytest.raises(ConfigError, match=r"\(with --set\): scenario.duration_s: Input should"):
        ta.load_config(cfg, ["run.trials=5"])
    assert ta.load_config(cfg, ["scenario.duration_s=600"]).scenario.duration_s == 600.0
    big = _write(tmp_path / "big.yaml", {"scenario": {"duration_s": 1e5}, "run": {"trials": 10**7}})
    with pytest.raises(ConfigError, match="trial-epochs"):
        ta.load_config(big)
    assert ta.load_config(big, ["run.trials=10"]).run.trials == 10
