"""`qkf bench`: the SPEC §8 files, reproducibility, sweeps, and no half-written output."""

from __future__ import annotations

import csv
import importlib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.methods import METHODS
from qkf.transfer_alignment.report import SUMMARY_COLUMNS
from qkf.transfer_alignment.states import STATE_COLUMNS
from tests.conftest import CONFIGS

runner = CliRunner()
SHORT = ["--set", "scenario.duration_s=400", "--set", "run.chunk_trials=3"]


def _bench(out: Path, *extra: str, config: str = "paper.yaml") -> None:
    args = [
        "bench",
        str(CONFIGS / config),
        "--trials",
        "5",
        "--seed",
        "4",
        "--out",
        str(out),
        "--quiet",
    ]
    result = runner.invoke(app, [*args, *SHORT, *extra])
    assert result.exit_code == 0, result.output + str(result.exception)


def _read(path: Path) -> list[list[str]]:
    with path.open() as f:
        return list(csv.reader(f))


PAPER_METHODS = "kf,kf-tuned,sage-husa,qkf,mmae"  # the source paper's five (cheap ones)


@pytest.mark.figures
def test_bench_writes_the_spec_files(tmp_path: Path) -> None:
    _bench(tmp_path, "--methods", PAPER_METHODS)
    names = {p.name for p in tmp_path.iterdir()}
    assert {
        "rms.csv",
        "summary.csv",
        "summary.md",
        "crlb.csv",
        "rms_groups.png",
        "rms_states.png",
    } <= names
    rms = _read(tmp_path / "rms.csv")
    assert tuple(rms[0]) == ("method", "t_s", *STATE_COLUMNS)
    methods = PAPER_METHODS.split(",")
    assert len(rms) == 1 + 5 * 400 and [r[0] for r in rms[1::400]] == methods
    rms = [r for r in rms if r[0] in ("method", "kf")]
    summary = _read(tmp_path / "summary.csv")
    assert tuple(summary[0]) == SUMMARY_COLUMNS
    assert [r[0] for r in summary[1:]] == methods
    row = dict(zip(summary[0], summary[1], strict=True))
    assert row["method"] == "kf" and row["trials"] == "5"
    # summary = RMS over the whole run / last 20 % of the per-epoch RMS, per group
    per_epoch = np.array([r[2:] for r in rms[1:]], dtype=float)
    ms_att = np.mean(per_epoch[:, 0:3] ** 2, axis=1)
    np.testing.assert_allclose(float(row["att_arcsec_avg"]), np.sqrt(ms_att.mean()), rtol=1e-12)
    np.testing.assert_allclose(
        float(row["att_arcsec_final"]), np.sqrt(ms_att[320:].mean()), rtol=1e-12
    )
    md = (tmp_path / "summary.md").read_text()
    assert "| kf | 5 |" in md and "CRLB" in md and "arcsec" in md
    assert "kf-tuned: κ =" in md
    # the κ chosen by the adaptive methods, per trial, every decision period (10 s)
    kappa = _read(tmp_path / "kappa.csv")
    assert tuple(kappa[0]) == ("method", "trial", "t_s", "kappa")
    assert {r[0] for r in kappa[1:]} == {"sage-husa", "qkf", "mmae"}
    qkf_rows = [r for r in kappa[1:] if r[0] == "qkf"]
    assert len(qkf_rows) == 5 * 40
    assert {float(r[3]) for r in qkf_rows} <= {10 ** (-2 + 0.4 * i) for i in range(11)}
    assert (tmp_path / "kappa.png").exists()
    assert (tmp_path / "rms_groups.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.slow  # three Monte Carlo benchmarks
def test_same_seed_same_numbers(tmp_path: Path) -> None:
    _bench(tmp_path / "a", "--methods", PAPER_METHODS)
    _bench(tmp_path / "b", "--methods", PAPER_METHODS)
    assert (tmp_path / "a/kappa.csv").read_bytes() == (tmp_path / "b/kappa.csv").read_bytes()
    assert (tmp_path / "a/rms.csv").read_bytes() == (tmp_path / "b/rms.csv").read_bytes()
    sa, sb = _read(tmp_path / "a/summary.csv"), _read(tmp_path / "b/summary.csv")
    assert [r[:-1] for r in sa] == [r[:-1] for r in sb]  # all but runtime_s
    _bench(tmp_path / "c", "--methods", "kf", "--seed", "5")
    kf_rows = [
        line for line in (tmp_path / "a/rms.csv").read_text().splitlines() if line.startswith("kf,")
    ]
    assert kf_rows != (tmp_path / "c/rms.csv").read_text().splitlines()[1:]


_CALLS = {"n": 0}


def flaky_kf(cfg, data):  # type: ignore[no-untyped-def]
    """A user method (``tests.test_bench:flaky_kf``) that fails on its second chunk."""
    _CALLS["n"] += 1
    if _CALLS["n"] == 2:
        raise RuntimeError("boom")
    return METHODS["kf"](cfg, data)


def test_a_failing_run_writes_nothing(tmp_path: Path) -> None:
    # the spec imports this file as ``tests.test_bench``, not necessarily pytest's module object
    calls = importlib.import_module("tests.test_bench")._CALLS
    calls["n"] = 0
    out = tmp_path / "out"
    args = [
        "bench",
        str(CONFIGS / "paper.yaml"),
        "--trials",
        "5",
        "--out",
        str(out),
        "--quiet",
        "--methods",
        "tests.test_bench:flaky_kf",
        *SHORT,
    ]
    result = runner.invoke(app, args)
    assert calls["n"] == 2  # the first chunk ran, the second failed
    assert result.exit_code != 0
    assert not out.exists()


def test_unknown_method_is_a_clear_error(tmp_path: Path) -> None:
    result = runner.invoke(
        app,
        [
            "bench",
            str(CONFIGS / "paper.yaml"),
            "--methods",
            "kf,nope",
            "--out",
            str(tmp_path / "o"),
        ],
    )
    assert result.exit_code == 2
    assert "nope" in result.stderr
    assert not (tmp_path / "o").exists()


def test_sweep_runs_once_per_value(tmp_path: Path) -> None:
    _bench(
        tmp_path, "--methods", "kf", "--set", "sweep.values=[1, 10]", config="noise_mismatch.yaml"
    )
    assert (tmp_path / "attitude_sigma_arcsec=1/summary.csv").exists()
    assert (tmp_path / "attitude_sigma_arcsec=10/summary.csv").exists()
    rows = _read(tmp_path / "sweep_summary.csv")
    assert rows[0][0] == "scenario.ads.attitude_sigma_arcsec"
    col = rows[0].index("att_arcsec_final")
    att = {r[0]: float(r[col]) for r in rows[1:]}
    assert att["10"] > 2 * att["1"]  # more ADS noise, worse attitude
