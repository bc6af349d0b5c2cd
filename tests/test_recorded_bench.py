"""Methods on recorded data: ``qkf bench CONFIG --data FILE`` (docs/recorded_data.md).

Round trip against the simulated run, the grid (held epochs, gaps, partial rows), the
truth-free measures on data with the filter's own noise and with a misspecified one, several
files as trials, a trained policy, and the command line (exit 2, nothing written).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.methods import resolve_method
from qkf.transfer_alignment.recorded.grid import load_recorded
from qkf.transfer_alignment.recorded.quality import (
    autocorrelation,
    block_quality,
    mean_band,
    nis_band,
)
from qkf.transfer_alignment.recorded.reader import RecordedDataError
from qkf.transfer_alignment.recorded.run import run_recorded
from qkf.transfer_alignment.recorded.writer import write_recorded
from qkf.transfer_alignment.scenario import simulate

ROOT = Path(__file__).resolve().parents[1]
POLICY = ROOT / "agents" / "zoo" / "best" / "model.zip"


def short(duration: float = 500.0, *extra: str):  # type: ignore[no-untyped-def]
    return load_config("paper", [f"scenario.duration_s={duration}", *extra])


def write(path: Path, cfg, seed: int = 7, trial: int = 0, truth: bool = True):  # type: ignore[no-untyped-def]
    data = simulate(cfg, seed, [trial])
    write_recorded(path, data, 0, truth=truth)
    return data


def rel_close(a: np.ndarray, b: np.ndarray, tol: float = 1e-12) -> bool:
    return bool(np.all(np.abs(a - b) <= tol * np.maximum(np.abs(b), 1e-300)))


@pytest.mark.parametrize("spec", ["kf", "glr", "imm", "alarm-burst"])
def test_round_trip_gives_the_simulated_estimates(tmp_path: Path, spec: str) -> None:
    cfg = short(400.0)
    data = write(tmp_path / "run.csv", cfg)
    rec = load_recorded(cfg, [tmp_path / "run.csv"])
    assert rec.has_truth and rec.data.n_epochs == data.n_epochs
    assert rec.cfg.scenario.dt_s == cfg.scenario.dt_s
    res = run_recorded(rec, spec, progress=False)
    method = resolve_method(spec).method
    direct = method(cfg, data)
    assert rel_close(res.methods[0].out.est, direct.est)
    # with truth it is an ordinary benchmark on the recorded trial
    assert res.bench is not None and res.bench.trials == 1


def test_held_epochs_are_exact_for_a_held_gyro(tmp_path: Path) -> None:
    """Dropping every other row of a run whose gyro is piecewise constant over two epochs
    gives the same estimates at the kept rows (a step of 2Δt = two steps of Δt)."""
    cfg = short(300.0, "filter.matching=attitude")
    data = simulate(cfg, 3, [0])
    gyro = data.gyro.copy()
    gyro[:, 1::2] = gyro[:, 0::2][:, : gyro[:, 1::2].shape[1]]
    meas = np.ones(data.n_epochs, dtype=bool)
    meas[1::2] = False
    from dataclasses import replace

    held = replace(data, gyro=gyro, has_meas=meas)
    kf = resolve_method("kf").method
    full = kf(cfg, held)
    # the file has every row of the first 60 % (the median step stays Δt) and then only the
    # even rows: each odd epoch after that is a dropped sample, filled in by holding the gyro
    keep = np.unique(np.append(np.arange(0, data.n_epochs, 2), data.n_epochs - 1))
    dense = np.unique(np.concatenate([np.arange(0, int(0.6 * data.n_epochs)), keep]))
    mixed = replace(
        held,
        t=data.t[dense],
        q_true=data.q_true[:, dense],
        bias=data.bias[:, dense],
        calib=data.calib[:, dense],
        gyro=gyro[:, dense],
        ads_q=data.ads_q[:, dense],
        ads_rate=data.ads_rate[:, dense],
        has_meas=meas[dense],
    )
    write_recorded(tmp_path / "mixed.csv", mixed, 0)
    rec = load_recorded(cfg, [tmp_path / "mixed.csv"])
    info = rec.files[0]
    assert rec.data.n_epochs == data.n_epochs
    assert info.held_epochs == data.n_epochs - dense.size > 0
    out = run_recorded(rec, "kf", progress=False).methods[0].out
    # a step of 2Δt with the reading held equals two steps of Δt (up to rounding in the
    # attitude integration: the quaternion is renormalised each step)
    np.testing.assert_allclose(out.est[0, dense, 4:], full.est[0, dense, 4:], rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(out.est[0, dense, :4], full.est[0, dense, :4], atol=1e-12)


def test_rows_without_every_measurement_do_not_update(tmp_path: Path) -> None:
    cfg = short(300.0)
    data = simulate(cfg, 5, [0])
    path = tmp_path / "partial.csv"
    write_recorded(path, data, 0)
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    rate_cols = [header.index(c) for c in ("ads_wx_rad_s", "ads_wy_rad_s", "ads_wz_rad_s")]
    for row in range(100, 110):  # data rows 100..109 lose their ADS rate
        cells = lines[row + 1].split(",")
        for c in rate_cols:
            cells[c] = ""
        lines[row + 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    rec = load_recorded(cfg, [path])
    assert rec.files[0].partial_rows == 10
    assert not rec.data.has_meas[100:110].any() and rec.data.has_meas[:100].all()
    att_only = load_recorded(short(300.0, "filter.matching=attitude"), [path])
    assert att_only.files[0].partial_rows == 0 and att_only.data.has_meas.all()


def test_gap_longer_than_the_limit_is_refused(tmp_path: Path) -> None:
    cfg = short(300.0, "recorded.max_gap_s=20")
    data = simulate(cfg, 5, [0])
    path = tmp_path / "gap.csv"
    write_recorded(path, data, 0)
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    ads = [header.index(c) for c in header if c.startswith("ads_")]
    for row in range(50, 75):  # 25 s without the ADS
        cells = lines[row + 1].split(",")
        for c in ads:
            cells[c] = ""
        lines[row + 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordedDataError, match=r"gap\.csv: row 76 \(line 77\).*max_gap_s"):
        load_recorded(cfg, [path])
    ok = load_recorded(short(300.0, "recorded.max_gap_s=30"), [path])
    assert not ok.data.has_meas[50:75].any()


def test_off_grid_time_is_refused(tmp_path: Path) -> None:
    cfg = short(100.0)
    data = simulate(cfg, 5, [0])
    from dataclasses import replace

    t = data.t.copy()
    t[40] += 0.3  # 0.3 s off a 1 s grid
    write_recorded(tmp_path / "jit.csv", replace(data, t=t), 0)
    with pytest.raises(RecordedDataError, match=r"jit\.csv: row 41 \(line 42\), column t_s"):
        load_recorded(cfg, [tmp_path / "jit.csv"])


def test_quality_measures_by_hand() -> None:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((4000, 3))
    rho = autocorrelation(x, 3)
    # by hand for lag 2, column 1
    xc = x[:, 1] - x[:, 1].mean()
    assert rho[1, 1] == pytest.approx(np.sum(xc[:-2] * xc[2:]) / np.sum(xc * xc))
    assert np.all(np.abs(rho) < 4 / np.sqrt(4000))
    lo, hi = nis_band(3)
    assert (lo, hi) == pytest.approx((0.2158, 9.348), abs=1e-3)
    m_lo, m_hi = mean_band(3, 1000)
    assert m_lo < 1 < m_hi and m_hi - m_lo < 0.25
    nis = np.sum(x**2, axis=1)  # χ²(3) draws: consistent
    good = block_quality("attitude", nis, x, np.ones(4000, dtype=bool))
    assert good.flags == () and abs(good.in_band - 0.95) < 0.02
    bad = block_quality("attitude", 4 * nis, 2 * x, np.ones(4000, dtype=bool))
    assert len(bad.flags) == 2 and "too small" in bad.flags[1]
    walk = np.cumsum(x, axis=0)  # strongly correlated innovations
    corr = block_quality("attitude", nis, walk, np.ones(4000, dtype=bool))
    assert any("correlated" in f for f in corr.flags)


@pytest.mark.slow
def test_nis_without_truth_fits_the_own_noise_and_flags_a_misspecified_one(
    tmp_path: Path,
) -> None:
    cfg = short(1500.0)
    write(tmp_path / "own.csv", cfg, seed=11, truth=False)
    rec = load_recorded(cfg, [tmp_path / "own.csv"])
    assert not rec.has_truth
    res = run_recorded(rec, "kf", progress=False)
    att = res.methods[0].quality[0][0]
    assert att.block == "attitude" and att.epochs == 1100
    assert att.in_band >= 0.90, att
    assert att.flags == (), att.flags
    # the ADS is noisier (10″) than the filter assumes (3″, the paper config)
    noisy = short(1500.0, "scenario.ads.attitude_sigma_arcsec=10")
    write(tmp_path / "noisy.csv", noisy, seed=11, truth=False)
    res = run_recorded(load_recorded(cfg, [tmp_path / "noisy.csv"]), "kf", progress=False)
    att = res.methods[0].quality[0][0]
    assert att.in_band < 0.5 and att.nis_mean > 5
    assert any("too small" in f for f in att.flags)


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


@pytest.mark.figures
def test_cli_without_truth_writes_estimates_quality_and_plots(tmp_path: Path) -> None:
    cfg = short(500.0)
    write(tmp_path / "tm.csv", cfg, truth=False)
    out = tmp_path / "run"
    r = CliRunner().invoke(
        app,
        ["bench", "paper", "--set", "scenario.duration_s=500", "--data", str(tmp_path / "tm.csv"),
         "--methods", "kf,imm", "--out", str(out), "--quiet"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    names = {p.name for p in out.iterdir()}
    assert {"estimates.csv", "quality.csv", "final.csv", "summary.md", "estimates.png",
            "nis.png", "run.json"} <= names  # fmt: skip
    assert "rms.csv" not in names  # no truth: no errors
    rows = read_csv(out / "estimates.csv")
    assert len(rows) == 2 * 500
    kf_rows = [r for r in rows if r["method"] == "kf"]
    assert float(kf_rows[-1]["t_s"]) == pytest.approx(499.0)
    assert float(kf_rows[-1]["bias_x_degph_sd"]) > 0
    assert kf_rows[-1]["kappa"] == ""  # kf does not choose κ (run.kappa throughout)
    imm_rows = [r for r in rows if r["method"] == "imm"]
    assert imm_rows[-1]["bias_x_degph_sd"] == ""  # a bank reports no per-epoch σ
    info = json.loads((out / "run.json").read_text())
    import hashlib

    digest = hashlib.sha256((tmp_path / "tm.csv").read_bytes()).hexdigest()
    assert info["data"][0]["sha256"] == digest and info["kind"] == "bench-recorded"
    md = (out / "summary.md").read_text()
    assert "Consistency without truth" in md and "Not judged" in md and "imm" in md
    final = read_csv(out / "final.csv")
    assert len(final) == 2 * 12


def test_cli_with_truth_over_several_files_gives_paired_intervals(tmp_path: Path) -> None:
    cfg = short(500.0)
    folder = tmp_path / "runs"
    folder.mkdir()
    for i in range(3):
        write(folder / f"r{i}.csv", cfg, seed=21, trial=i)
    out = tmp_path / "run"
    r = CliRunner().invoke(
        app,
        ["bench", "paper", "--set", "scenario.duration_s=500", "--data", str(folder),
         "--methods", "kf,glr", "--out", str(out), "--quiet"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    paired = read_csv(out / "paired.csv")
    assert {p["method"] for p in paired} == {"glr"}
    trials = read_csv(out / "trials.csv")
    assert sorted({t["trial"] for t in trials}) == ["0", "1", "2"]
    info = json.loads((out / "run.json").read_text())
    assert info["kind"] == "bench" and len(info["data"]) == 3 and info["trials"] == 3


@pytest.mark.slow
def test_a_trained_policy_runs_on_recorded_data(tmp_path: Path) -> None:
    # judged from 100 s: a run that ends before run.settled_s has no judged window
    cfg = short(400.0, "run.settled_s=100")
    write(tmp_path / "p.csv", cfg, truth=False)
    rec = load_recorded(cfg, [tmp_path / "p.csv"])
    res = run_recorded(rec, f"kf,policy:{POLICY}", progress=False)
    pol = res.methods[1]
    assert pol.name == "policy:best"
    assert pol.out.kappa is not None and np.isfinite(pol.out.est).all()
    assert pol.out.nis is not None and pol.quality[0][0].epochs > 0


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("t_s,gyro_wx_rad_s\n0,0\n", "missing"),
        ("", "empty"),
    ],
)
def test_cli_bad_data_exit_2_nothing_written(tmp_path: Path, content: str, match: str) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    out = tmp_path / "run"
    r = CliRunner().invoke(
        app, ["bench", "paper", "--data", str(bad), "--methods", "kf", "--out", str(out)]
    )
    assert r.exit_code == 2, r.output
    assert "bad.csv" in r.output and match in r.output.lower()
    assert not out.exists()


def test_cli_refuses_trials_with_data(tmp_path: Path) -> None:
    r = CliRunner().invoke(
        app,
        ["bench", "paper", "--data", str(tmp_path), "--trials", "3", "--out", str(tmp_path / "o")],
    )
    assert r.exit_code == 2 and "--trials" in r.output


def test_files_on_different_grids_are_refused(tmp_path: Path) -> None:
    write(tmp_path / "a.csv", short(300.0))
    write(tmp_path / "b.csv", short(310.0))
    with pytest.raises(RecordedDataError, match="share the grid"):
        load_recorded(short(300.0), [tmp_path / "a.csv", tmp_path / "b.csv"])


def test_record_command_never_overwrites(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    r = CliRunner().invoke(
        app, ["record", "paper", "--set", "scenario.duration_s=50", "--out", str(path)]
    )
    assert r.exit_code == 0, r.output
    before = path.read_bytes()
    r = CliRunner().invoke(
        app, ["record", "paper", "--set", "scenario.duration_s=60", "--out", str(path)]
    )
    assert r.exit_code == 2 and path.read_bytes() == before


@pytest.mark.parametrize("spec", ["alarm-burst", "qkf"])
def test_per_epoch_records_equal_the_filter_replayed_with_the_kappa_trace(spec: str) -> None:
    """σ and NIS a κ-schedule method reports are those of the plain filter run with the κ it
    chose (its blocks' records put together in the right epochs)."""
    from qkf.transfer_alignment.methods.oracle import run_schedule

    cfg = short(300.0)
    data = simulate(cfg, 4, [0, 1])
    out = resolve_method(spec).method(cfg, data)
    assert out.kappa is not None and out.var is not None and out.nis is not None
    replay = run_schedule(cfg, data, out.kappa)
    assert replay.var is not None and replay.nis is not None and replay.innov is not None
    np.testing.assert_allclose(out.var, replay.var, rtol=1e-12)
    np.testing.assert_allclose(out.nis, replay.nis, rtol=1e-9)
    np.testing.assert_allclose(out.innov, replay.innov, rtol=1e-9, atol=1e-20)


def test_cli_round_trip_estimates_csv_equals_the_simulated_filter(tmp_path: Path) -> None:
    """qkf record → qkf bench --data: estimates.csv holds the simulated run's estimates."""
    from qkf.transfer_alignment.recorded.outputs import CALIBRATION_COLUMNS
    from qkf.transfer_alignment.states import DISPLAY_UNIT

    sets = ["--set", "scenario.duration_s=300", "--set", "run.settled_s=100"]
    data_file = tmp_path / "sim.csv"
    r = CliRunner().invoke(app, ["record", "thermal_snap", *sets, "--seed", "5", "--trial", "2",
                                 "--out", str(data_file)])  # fmt: skip
    assert r.exit_code == 0, r.output
    out = tmp_path / "run"
    r = CliRunner().invoke(app, ["bench", "thermal_snap", *sets, "--data", str(data_file),
                                 "--methods", "kf", "--out", str(out), "--quiet"])  # fmt: skip
    assert r.exit_code == 0, r.output
    cfg = load_config("thermal_snap", ["scenario.duration_s=300"])
    direct = resolve_method("kf").method(cfg, simulate(cfg, 5, [2]))
    rows = read_csv(out / "estimates.csv")
    got = np.array([[float(row[c]) for c in CALIBRATION_COLUMNS] for row in rows])
    q = np.array([[float(row[c]) for c in ("qx", "qy", "qz", "qw")] for row in rows])
    assert rel_close(got, direct.est[0, :, 4:] / DISPLAY_UNIT[3:])
    assert rel_close(q, direct.est[0, :, :4])
    assert (out / "rms.csv").is_file() and (out / "paired.csv").exists() is False  # one method
