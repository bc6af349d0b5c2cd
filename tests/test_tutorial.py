"""docs/tutorial.py, the tutorial (a jupytext script), runs from start to end with tiny sizes
(issue 32 item 6): it trains, judges, plots the κ trace and reads the results in pandas."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT


@pytest.mark.slow
def test_the_tutorial_runs(tmp_path: Path) -> None:
    out = tmp_path / "tutorial"
    env = {**os.environ, "QKF_TUTORIAL_SMALL": "1", "QKF_TUTORIAL_OUT": str(out),
           "NUMBA_NUM_THREADS": "1"}  # fmt: skip
    run = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "tutorial.py")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    assert (out / "policy" / "model.zip").is_file()
    assert (out / "kappa_trace.png").read_bytes()[:4] == b"\x89PNG"
    assert "ratio_vs_kf_tuned" in run.stdout and "mine" in run.stdout
    families = (out / "families" / "families.csv").read_text()
    for name in ("kf-tuned", "glr", "mine", "steady_random", "thermal_snap_random"):
        assert name in families
    # a second run refuses to write into the first one's folder
    again = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "tutorial.py")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert again.returncode != 0 and "not empty" in again.stderr
