"""Backends give the same numbers: in-process, a local process pool, and Ray tasks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from qkf.transfer_alignment.benchmark import run_benchmark
from tests.conftest import cfg_with

SETS = ("scenario.duration_s=300", "run.chunk_trials=2")
METHODS = ["kf", "qkf", "sage-husa"]


def _rms(res) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
    return {m.name: m.rms for m in res.methods}


@pytest.fixture(scope="module")
def inline():  # type: ignore[no-untyped-def]
    return run_benchmark(cfg_with(*SETS), METHODS, trials=5, seed=3, progress=False)


def test_process_pool_matches_in_process(inline) -> None:  # type: ignore[no-untyped-def]
    pool = run_benchmark(cfg_with(*SETS), METHODS, trials=5, seed=3, progress=False, workers=2)
    for name, rms in _rms(inline).items():
        np.testing.assert_array_equal(_rms(pool)[name], rms)
    for a, b in zip(inline.methods, pool.methods, strict=True):
        if a.kappa is not None:
            np.testing.assert_array_equal(a.kappa, b.kappa)


@pytest.mark.slow
def test_ray_matches_local(inline, ray_cluster: Path) -> None:  # type: ignore[no-untyped-def]
    res = run_benchmark(cfg_with(*SETS), METHODS, trials=5, seed=3, progress=False, backend="ray")
    for name, rms in _rms(inline).items():
        np.testing.assert_array_equal(_rms(res)[name], rms)


def test_unknown_backend() -> None:
    with pytest.raises(ValueError, match="unknown backend"):
        run_benchmark(cfg_with(*SETS), ["kf"], trials=1, progress=False, backend="slurm")
