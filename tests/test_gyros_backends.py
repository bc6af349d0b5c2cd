"""``qkf gyros bench`` on the core Monte Carlo runner: the ``local`` backend in this process and
in a process pool, and ``ray``, write byte-identical CSV files; a chunked run equals an
unchunked one; a trial is reproducible on its own; the options are checked as ``qkf bench``
checks them, and recorded in run.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.benchmark import (
    METHODS,
    BenchResult,
    FdiChunk,
    UkfChunk,
    plan_bench,
    run_bench,
    run_chunk,
)
from qkf.redundant_gyros.cli import app
from qkf.redundant_gyros.fdi import Detectors
from qkf.redundant_gyros.geometry import build_unit

runner = CliRunner()
# small but complete: two fault kinds, 7 trials over 5 gyros (gyros 0 and 1 carry two trials,
# so chunks of 1 split them), and the UKF accuracy run on a short scenario
SETS = (
    "bench.kinds=[bias_step, stuck]",
    "bench.sizes_sigma=[8]",
    "bench.duration_s=40",
    "bench.fault_time_s=20",
    "bench.ukf_trials=2",
    "scenario.duration_s=75",
)
CLI_SETS = [arg for s in SETS for arg in ("--set", s)]
CSV_FILES = ("bench.csv", "ukf.csv")


def _bench(folder: Path, *extra: str) -> Path:
    res = runner.invoke(
        app,
        [
            *("bench", "five_gyros_s_bias", "--trials", "7", "--seed", "3", "--quiet"),
            *CLI_SETS,
            *("--set", "bench.chunk_trials=1", *extra, "--out", str(folder)),
        ],
    )
    assert res.exit_code == 0, res.output
    return folder


@pytest.fixture(scope="module")
def in_process(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _bench(tmp_path_factory.mktemp("gyros") / "local")


def _same_csv(a: Path, b: Path) -> None:
    for name in CSV_FILES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_process_pool_writes_the_same_files(in_process: Path, tmp_path: Path) -> None:
    pool = _bench(tmp_path / "pool", "--workers", "2")
    _same_csv(in_process, pool)
    info = json.loads((pool / "run.json").read_text())
    assert (info["backend"], info["workers"]) == ("local", 2)
    first = json.loads((in_process / "run.json").read_text())
    assert (first["backend"], first["workers"]) == ("local", 1)


def test_ray_writes_the_same_files(in_process: Path, tmp_path: Path, ray_cluster: Path) -> None:
    folder = _bench(tmp_path / "ray", "--backend", "ray")
    _same_csv(in_process, folder)
    info = json.loads((folder / "run.json").read_text())
    assert info["backend"] == "ray"


def _same_result(a: BenchResult, b: BenchResult) -> None:
    assert [(r.method, r.kind, r.size_sigma, r.trials, r.never_detected) for r in a.rows] == [
        (r.method, r.kind, r.size_sigma, r.trials, r.never_detected) for r in b.rows
    ]
    for ra, rb in zip(a.rows, b.rows, strict=True):
        assert ra.metrics == rb.metrics  # Estimate: value, lo, hi, compared exactly
    assert a.ukf is not None and b.ukf is not None
    for name in ("rms", "sd", "nees"):
        np.testing.assert_array_equal(getattr(a.ukf, name), getattr(b.ukf, name))
    assert a.ukf.converged_step == b.ukf.converged_step
    assert a.fdi_epochs == b.fdi_epochs


def test_a_chunked_run_equals_an_unchunked_one() -> None:
    chunked = run_bench(
        load_config("five_gyros_s_bias", [*SETS, "bench.chunk_trials=1"]), 7, 3, progress=False
    )
    whole = run_bench(
        load_config("five_gyros_s_bias", [*SETS, "bench.chunk_trials=64"]), 7, 3, progress=False
    )
    _same_result(chunked, whole)


def test_the_plan_numbers_every_trial_once_and_a_trial_runs_alone() -> None:
    cfg = load_config("five_gyros_s_bias", [*SETS, "bench.chunk_trials=2"])
    unit = build_unit(cfg)
    plan, note = plan_bench(cfg, unit, 7)
    assert note == "" and plan.ukf is not None
    chunks = plan.chunks()
    ids = np.concatenate(chunks)
    assert sorted(ids.tolist()) == list(range(plan.ukf_offset + plan.ukf.trials))
    det = Detectors.build(unit, cfg.fdi)
    # trial 5 of group 1 (stuck): gyro 0 carries trials 0 and 5, one chunk of two
    chunk = next(c for c in chunks if plan.ukf_offset > c[0] >= plan.trials and 5 in c % 7)
    together = run_chunk(cfg, det, plan, 3, chunk)
    alone = run_chunk(cfg, det, plan, 3, chunk[chunk % 7 == 5])
    assert isinstance(together, FdiChunk) and isinstance(alone, FdiChunk)
    row = int(np.flatnonzero(chunk % 7 == 5)[0])
    for m in METHODS:
        for f in ("false_alarms", "detected", "correct", "delay_s"):
            np.testing.assert_array_equal(
                getattr(alone.counts[m], f), getattr(together.counts[m], f)[row : row + 1]
            )
    ukf = run_chunk(cfg, det, plan, 3, np.array([plan.ukf_offset + 1]))
    assert isinstance(ukf, UkfChunk) and ukf.err.shape[0] == 1
    with pytest.raises(ValueError, match="one fault group"):
        run_chunk(cfg, det, plan, 3, np.array([0, 1]))  # two faulty gyros in one chunk


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--backend", "slurm"], "--backend: 'slurm' is not local or ray"),
        (["--workers", "0"], "--workers must be at least 1"),
    ],
)
def test_bad_backend_options_exit_2_writing_nothing(
    option: list[str], message: str, tmp_path: Path
) -> None:
    res = runner.invoke(app, ["bench", "five_gyros", *option, "--out", str(tmp_path / "b")])
    assert res.exit_code == 2
    assert message in " ".join(res.output.split())
    assert list(tmp_path.iterdir()) == []
