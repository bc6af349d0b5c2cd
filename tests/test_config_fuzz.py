"""Fuzzing the config loader: whatever a file or an override holds — random nesting, types,
unicode, huge and negative numbers, NaN and infinities, bytes that are not text — loading either
gives a valid config or one ``ConfigError``; through the command line, exit code 2 and one
message, never a traceback."""

from __future__ import annotations

import math
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core.config import ConfigError
from qkf.transfer_alignment.config import Config, load_config

runner = CliRunner()

# keys that exist (so the fuzzer reaches deep into the schema) and keys that do not
REAL_KEYS = [
    "name", "scenario", "filter", "run", "adaptive", "sweep", "dt_s", "duration_s", "maneuvers",
    "start_s", "axis", "rate_deg_s", "truth", "bias_degph", "misalignment_urad", "ads", "gaps",
    "end_s", "calibration_jumps", "t_s", "trials", "seed", "qp0", "matching", "actions", "count",
    "log10_min", "log10_step", "calibration_walk", "segments", "sigma_per_sqrt_s", "key", "values",
]  # fmt: skip
keys = st.one_of(st.sampled_from(REAL_KEYS), st.text(min_size=1, max_size=12))
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
    st.sampled_from(["x", "y", "z", "attitude", "attitude_rate", "1e400", "-inf", ".nan"]),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(keys, inner, max_size=4)),
    max_leaves=25,
)
documents = st.dictionaries(keys, values, max_size=6)

FUZZ = settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def _finite_everywhere(cfg: Config) -> bool:
    def walk(x: object) -> bool:
        if isinstance(x, float):
            return math.isfinite(x)
        if isinstance(x, dict):
            return all(walk(v) for v in x.values())
        if isinstance(x, list | tuple):
            return all(walk(v) for v in x)
        return True

    return walk(cfg.model_dump())


@FUZZ
@given(doc=documents)
def test_loader_accepts_or_refuses_cleanly(tmp_path_factory, doc) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("fuzz") / "cfg.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True))
    try:
        cfg = load_config(path)
    except ConfigError as exc:
        msg = str(exc)
        assert str(path) in msg and "Traceback" not in msg
    else:
        assert _finite_everywhere(cfg)


@FUZZ
@given(key=st.lists(keys, min_size=1, max_size=4), value=st.text(max_size=30))
def test_overrides_accept_or_refuse_cleanly(key, value) -> None:  # type: ignore[no-untyped-def]
    item = ".".join(key) + "=" + value
    try:
        cfg = load_config("paper", [item])
    except ConfigError as exc:
        assert "Traceback" not in str(exc)
    else:
        assert _finite_everywhere(cfg)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(blob=st.binary(max_size=200))
def test_arbitrary_bytes_are_refused_with_one_message(tmp_path_factory, blob) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("bytes") / "cfg.yaml"
    path.write_bytes(blob)
    try:
        load_config(path)
    except ConfigError as exc:
        assert str(path) in str(exc)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(doc=documents)
def test_command_line_exits_2_without_traceback(tmp_path_factory, doc) -> None:  # type: ignore[no-untyped-def]
    """``--trials 0`` stops a valid config right after loading, so every example exits 2."""
    folder = tmp_path_factory.mktemp("cli")
    path = folder / "cfg.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True))
    result = runner.invoke(
        app, ["bench", str(path), "--trials", "0", "--quiet", "--out", str(folder / "out")]
    )
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    # one message: a single "error:" header (a field named "error" appears inside it as well)
    assert [line.startswith("error:") for line in result.output.splitlines()].count(True) == 1
    assert not (folder / "out").exists()


def test_non_finite_and_huge_values_are_refused(tmp_path: Path) -> None:
    for sets, field in [
        (["scenario.truth.bias_degph=[.nan, 0, 0]"], "scenario.truth.bias_degph.0"),
        (["scenario.maneuvers.0.rate_deg_s=.inf"], "scenario.maneuvers.0.rate_deg_s"),
        (["scenario.duration_s=1e30"], "scenario"),
        (["run.trials=1000000000000"], "run.trials"),
    ]:
        try:
            load_config("paper", sets)
        except ConfigError as exc:
            assert field in str(exc)
        else:
            raise AssertionError(f"{sets} was accepted")
