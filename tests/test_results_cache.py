"""The results cache (issue 32, docs/caching.md): a cached result is the fresh one byte for byte,
a damaged entry is caught by its checksum and recomputed, and anything in the key that changes
(a config value, the code, a policy's model file) makes a miss."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, cfg_with
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core.results_cache import (
    CorruptEntry,
    Entry,
    ResultsCache,
    decode,
    describe,
    encode,
)
from qkf.transfer_alignment import chunk_cache
from qkf.transfer_alignment.benchmark import CacheWarning, run_benchmark
from qkf.transfer_alignment.report import bench_tables

POLICY = ROOT / "agents" / "zoo" / "best" / "model.zip"
SETS = ("scenario.duration_s=500", "run.settled_s=300", "run.chunk_trials=2")
"""Short trials, two chunks of a 3-trial run (a chunk is the unit the cache stores)."""


@pytest.fixture
def cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A results cache of the test's own, turned on (the suite turns it off by default)."""
    monkeypatch.setenv("QKF_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("QKF_NO_CACHE", raising=False)
    return tmp_path / "cache"


def _tables(res):  # type: ignore[no-untyped-def]
    return bench_tables(res)


def _bench(methods: str, *sets: str, cache: bool = True):  # type: ignore[no-untyped-def]
    cfg = cfg_with(*SETS, *sets)
    return run_benchmark(cfg, methods, trials=3, seed=7, progress=False, cache=cache)


# One method of each kind: a plain function (kf), the compiled filter bank (imm), methods
# tuned on the tuning seeds (kf-tuned, clock: their tuning is cached too), a yardstick object
# (hindsight), the batch solver, and a saved policy.
KINDS = ["kf", "imm", "kf-tuned", "clock", "hindsight", "batch", f"policy:{POLICY}"]
TUNED = ("kf-tuned", "clock")


@pytest.mark.slow
@pytest.mark.parametrize("method", KINDS)
def test_a_cached_result_is_the_fresh_one_byte_for_byte(cache_dir: Path, method: str) -> None:
    sets = ("adaptive.tuned.trials=2",) if method in TUNED else ()
    fresh = _bench(method, *sets, cache=False)
    stored = _bench(method, *sets)  # computes and stores
    served = _bench(method, *sets)  # reads back
    name = fresh.methods[0].name
    chunks = ("hit", "miss", "corrupt", "off")
    assert [stored.cache[name][k] for k in chunks] == [0, 2, 0, 0]
    assert [served.cache[name][k] for k in chunks] == [2, 0, 0, 0]
    assert fresh.cache[name]["off"] == 2
    if method in TUNED:  # the tuning on the tuning seeds is cached too
        assert stored.cache[name]["prepare_miss"] == served.cache[name]["prepare_hit"] == 1
        assert "prepare_hit" not in fresh.cache[name]
    # every file of the run, byte for byte; run times are the computing run's, so the stored
    # run and the served one agree on them too, and the fresh one only on everything else
    assert _tables(served) == _tables(stored)
    for a, b in zip(fresh.methods, served.methods, strict=True):
        for field in ("rms", "trial_values", "kappa", "band", "nees", "nees_trials"):
            x, y = getattr(a, field), getattr(b, field)
            assert (x is None) == (y is None)
            if x is not None:
                assert np.array_equal(x, y, equal_nan=True), field
        assert list(a.summary) == list(b.summary)
        assert np.array_equal(list(a.summary.values()), list(b.summary.values()), equal_nan=True)
        # notes may carry a wall time (hindsight's): the stored run's, compared in the tables
        assert a.divergences == b.divergences


def test_a_damaged_entry_is_reported_and_recomputed(cache_dir: Path) -> None:
    first = _bench("kf")
    entries = ResultsCache().entries()
    assert len(entries) == 2
    raw = entries[0].read_bytes()
    entries[0].write_bytes(raw[: len(raw) // 2])  # truncated
    with pytest.warns(CacheWarning, match="checksum"):
        again = _bench("kf")
    assert again.cache["kf"] == {"hit": 1, "miss": 0, "corrupt": 1, "off": 0}
    assert len(again.cache_problems) == 1 and str(entries[0]) in again.cache_problems[0]
    assert _tables(again)["trials.csv"] == _tables(first)["trials.csv"]
    # rewritten whole: the next run is all hits, without a warning
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        assert _bench("kf").cache["kf"]["hit"] == 2


def test_a_config_value_or_the_code_changes_the_key(
    cache_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _bench("kf")
    assert _bench("kf").cache["kf"]["hit"] == 2
    # a value the method's results depend on
    assert _bench("kf", "scenario.ads.attitude_sigma_arcsec=4.0").cache["kf"]["miss"] == 2
    # what only says how the run is carried out is not in the key
    assert _bench("kf", "run.bootstrap.resamples=200").cache["kf"]["hit"] == 2
    # another code fingerprint (an edited source file)
    real = chunk_cache.code_fingerprint
    monkeypatch.setattr(
        chunk_cache, "code_fingerprint", lambda dirs: {**real(dirs), "sources": "edited"}
    )
    assert _bench("kf").cache["kf"]["miss"] == 2


def test_a_policy_is_keyed_by_its_model_file(cache_dir: Path, tmp_path: Path) -> None:
    from agents.policy import PolicyMethod

    copy = tmp_path / "policy"
    shutil.copytree(POLICY.parent, copy)
    token = PolicyMethod(str(copy / "model.zip")).cache_token()
    assert len(token["model_sha256"]) == 64
    with (copy / "model.zip").open("ab") as fh:  # another model file at the same path
        fh.write(b"\0")
    assert PolicyMethod(str(copy / "model.zip")).cache_token() != token


def test_no_cache_and_the_environment_switch(
    cache_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert _bench("kf", cache=False).cache["kf"]["off"] == 2
    monkeypatch.setenv("QKF_NO_CACHE", "1")
    assert _bench("kf").cache["kf"]["off"] == 2
    assert ResultsCache().entries() == []


def test_entry_checksum_and_key() -> None:
    key = {"a": 1}
    entry = Entry({"x": np.arange(5.0), "n": np.array([1, 2])}, {"notes": {"k": "v"}})
    raw = encode(key, entry)
    back = decode(raw, key)
    assert back is not None and back.meta == entry.meta
    assert all(np.array_equal(back.arrays[k], entry.arrays[k]) for k in entry.arrays)
    assert decode(raw, {"a": 2}) is None  # written for another key
    flipped = bytearray(raw)
    flipped[-10] ^= 0xFF
    with pytest.raises(CorruptEntry, match="checksum"):
        decode(bytes(flipped), key)
    with pytest.raises(CorruptEntry):
        decode(b"garbage", key)


def test_methods_from_outside_the_package_are_not_cached() -> None:
    from qkf.transfer_alignment.methods import resolve_method

    assert describe(resolve_method("kf").method) == "qkf.transfer_alignment.methods.fixed:run_kf"
    assert describe(np.linalg.norm) is None  # code the fingerprint does not cover
    assert describe(lambda cfg, data: None) is None


def test_cache_info_and_clear_touch_only_entries(cache_dir: Path) -> None:
    _bench("kf")
    foreign = cache_dir / "results" / "notes.txt"
    foreign.write_text("a file of the user's")
    runner = CliRunner()
    info = runner.invoke(app, ["cache", "info"])
    assert info.exit_code == 0, info.output
    assert "2 entries" in info.output
    cleared = runner.invoke(app, ["cache", "clear"])
    assert cleared.exit_code == 0, cleared.output
    assert "removed 2" in cleared.output
    assert ResultsCache().entries() == [] and foreign.exists()


def test_qkf_bench_uses_the_cache_and_run_json_counts_it(cache_dir: Path, tmp_path: Path) -> None:
    import json

    runner = CliRunner()
    args = ["bench", "paper", "--methods", "kf", "--trials", "2", "--quiet",
            "--set", "scenario.duration_s=500", "--set", "run.settled_s=300"]  # fmt: skip
    counts = []
    for i, extra in enumerate(([], [], ["--no-cache"])):
        out = tmp_path / f"run{i}"
        result = runner.invoke(app, [*args, *extra, "--out", str(out)])
        assert result.exit_code == 0, result.output
        counts.append(json.loads((out / "run.json").read_text())["cache"]["kf"])
    assert [c["miss"] for c in counts] == [1, 0, 0]
    assert [c["hit"] for c in counts] == [0, 1, 0]
    assert counts[2]["off"] == 1
    for name in ("trials.csv", "rms.csv"):
        assert (tmp_path / "run0" / name).read_bytes() == (tmp_path / "run1" / name).read_bytes()
        assert (tmp_path / "run0" / name).read_bytes() == (tmp_path / "run2" / name).read_bytes()
