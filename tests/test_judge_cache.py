"""``qkf judge`` and the results cache, for any problem (docs/caching.md): a judged method's
per-trial results are stored once and read back byte for byte, every lookup is counted in
run.json, a damaged entry is found by its checksum, reported and recomputed (never used), and two
methods made by one factory (closures) never share an entry."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core.results_cache import ResultsCache, describe
from qkf.redundant_gyros.methods import GYRO_METHODS

runner = CliRunner()
GYRO_SHORT = ["--set", "scenario.duration_s=160"]  # judged from 100 s on
METHODS = "constant,constant-mixed,clock-mixed"  # two closures of one factory


def _judge(out: Path, *extra: str, methods: str = METHODS) -> dict[str, object]:
    res = runner.invoke(
        app,
        ["judge", "redundant_gyros", "--methods", methods, "--families", "gyro_control",
         "--trials", "3", "--out", str(out), "--no-progress", *GYRO_SHORT, *extra],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    info = json.loads((out / "run.json").read_text())
    return {"output": res.output, "cache": info["cache"]}


def _lookups(run: dict[str, object], status: str) -> dict[str, int]:
    cache = run["cache"]
    assert isinstance(cache, dict)
    return {label: counts[status] for label, counts in cache["gyro_control"]["lookups"].items()}


def test_a_cached_judgement_is_the_fresh_one_and_a_damaged_entry_is_recomputed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, bare_gyro_policy: str
) -> None:
    """Plain methods, two closures of one factory and a saved policy: stored once, read back
    byte for byte; a truncated entry recomputed; a policy retrained into the same path is a
    miss (its key holds the model's SHA-256)."""
    monkeypatch.setenv("QKF_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("QKF_NO_CACHE", raising=False)
    methods = f"{METHODS},policy:{bare_gyro_policy}"
    labels = [*METHODS.split(","), "policy:gyro_ppo"]
    fresh = _judge(tmp_path / "fresh", "--no-cache", methods=methods)
    assert fresh["cache"] == "off"
    assert not (tmp_path / "cache").exists()  # --no-cache neither reads nor writes

    first = _judge(tmp_path / "first", methods=methods)
    assert _lookups(first, "miss") == dict.fromkeys(labels, 1)
    entries = ResultsCache(tmp_path / "cache").entries()
    assert len(entries) == len(labels)  # one per method: the -mixed closures do not collide
    second = _judge(tmp_path / "second", methods=methods)
    assert _lookups(second, "hit") == dict.fromkeys(labels, 1)
    for run in ("first", "second"):
        for name in ("trials.csv", "versus.csv", "versus.md"):
            assert (tmp_path / run / name).read_bytes() == (tmp_path / "fresh" / name).read_bytes()

    damaged = entries[0]
    damaged.write_bytes(damaged.read_bytes()[:-40])  # truncated: the checksum no longer holds
    with pytest.warns(UserWarning, match="damaged results-cache entry"):
        third = _judge(tmp_path / "third", methods=methods)
    assert sum(_lookups(third, "corrupt").values()) == 1
    assert sum(_lookups(third, "hit").values()) == len(labels) - 1
    cache = third["cache"]
    assert isinstance(cache, dict) and len(cache["gyro_control"]["damaged"]) == 1
    assert "damaged results-cache entries recomputed" in str(third["output"])
    assert (tmp_path / "third" / "trials.csv").read_bytes() == (
        tmp_path / "fresh" / "trials.csv"
    ).read_bytes()

    model = Path(bare_gyro_policy.split("@")[0])
    model.write_bytes(model.read_bytes() + b"\0")  # another model file at the same path
    fourth = _judge(tmp_path / "fourth", methods=methods)
    assert _lookups(fourth, "miss")["policy:gyro_ppo"] == 1  # not the old policy's result
    assert _lookups(fourth, "hit") == {**dict.fromkeys(labels, 1), "policy:gyro_ppo": 0}


def test_the_environment_switch_turns_the_cache_off(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("QKF_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("QKF_NO_CACHE", "1")
    assert _judge(tmp_path / "off")["cache"] == "off"
    assert not (tmp_path / "cache").exists()


def test_closures_of_one_factory_are_described_by_what_they_captured() -> None:
    a, b = describe(GYRO_METHODS["constant-mixed"]), describe(GYRO_METHODS["clock-mixed"])
    assert a is not None and b is not None and a != b
    assert describe(GYRO_METHODS["constant-mixed"]) == a  # the same method: the same key

    def make(value: object) -> object:
        def inner() -> object:
            return value

        return inner

    assert describe(make(1)) is None  # defined outside qkf: its code is not in the fingerprint
