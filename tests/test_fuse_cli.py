"""``qkf fuse``: the output contract, reproducibility, data files giving the same result as the
simulation they came from, and bad input refused with file, row and column (exit 2, nothing
written)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.sca_fusion.config import load_config
from qkf.sca_fusion.scenario import simulate

SHORT = [
    "--set",
    "simulation.duration_s=400",
    "--set",
    "simulation.sca_gaps=[{start_s: 100, end_s: 110}]",
    "--set",
    "simulation.data_gaps=[{start_s: 300, end_s: 305}]",
]
FILES = {
    "fused.csv": ["t_s", "q_x", "q_y", "q_z", "q_w", "sigma_x_rad", "sigma_y_rad", "sigma_z_rad"],
    "variance_components.csv": ["arc", "group", "axis", "sigma"],
    "solution.csv": ["arc", "parameter", "value", "sd"],
    "epoch_sigma.csv": ["t_s", "sca", "acc"],
    "acc_calibrated.csv": ["t_s", "dw_x", "dw_y", "dw_z"],
}


def invoke(*args: str) -> tuple[int, str]:
    res = CliRunner().invoke(app, ["fuse", *args])
    return res.exit_code, res.output


def read(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fuse") / "sim"
    code, text = invoke("sca_acc_fusion", *SHORT, "--out", str(out), "--quiet")
    assert code == 0, text
    return out


@pytest.mark.figures
def test_outputs_follow_the_contract(simulated: Path) -> None:
    names = {p.name for p in simulated.iterdir()}
    assert set(FILES) | {"summary.md", "residuals.png", "epoch_sigma.png", "spectra.png"} <= names
    for name, header in FILES.items():
        with (simulated / name).open() as f:
            assert next(csv.reader(f)) == header, name
    fused = read(simulated / "fused.csv")
    assert len(fused) == 401 - 5  # the data gap; the 5-s piece after it forms a second arc
    q = np.array([[float(r[k]) for k in ("q_x", "q_y", "q_z", "q_w")] for r in fused])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    sig = np.array([[float(r[f"sigma_{a}_rad"]) for a in "xyz"] for r in fused])
    assert np.all(sig > 0) and np.all(sig < 1e-3)
    vc = read(simulated / "variance_components.csv")
    assert {(r["arc"], r["group"], r["axis"]) for r in vc} == {
        ("0", "sca", "all"),
        ("0", "acc", "x"),
        ("0", "acc", "y"),
        ("0", "acc", "z"),
        ("1", "sca", "all"),
        ("1", "acc", "x"),
        ("1", "acc", "y"),
        ("1", "acc", "z"),
    }
    sol = read(simulated / "solution.csv")
    assert [r["parameter"] for r in sol if r["arc"] == "0"] == [
        "acc_bias_x",
        "acc_bias_y",
        "acc_bias_z",
    ]
    es = read(simulated / "epoch_sigma.csv")
    gap = [r for r in es if 100 <= float(r["t_s"]) < 110]
    assert gap and all(r["sca"] == "" and float(r["acc"]) >= 1.0 for r in gap)
    assert all(float(r["sca"]) >= 1.0 for r in es if r["sca"])
    text = (simulated / "summary.md").read_text()
    assert "Against the simulated truth" in text and "| 1 | 305 |" in text


def test_simulation_is_reproducible(simulated: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    code, text = invoke("sca_acc_fusion", *SHORT, "--out", str(again), "--quiet")
    assert code == 0, text
    for name in [*FILES, "summary.md"]:
        assert (again / name).read_bytes() == (simulated / name).read_bytes(), name
    other = tmp_path / "other"
    code, _ = invoke("sca_acc_fusion", *SHORT, "--seed", "7", "--out", str(other), "--quiet")
    assert code == 0
    assert (other / "fused.csv").read_bytes() != (simulated / "fused.csv").read_bytes()


def write_csv(path: Path, header: list[str], rows: np.ndarray | list[list[object]]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in rows:
            w.writerow([repr(float(v)) if isinstance(v, float | np.floating) else v for v in row])
    return path


def simulated_files(tmp_path: Path) -> tuple[Path, Path]:
    """The data of the SHORT simulation as input files (quaternion signs flipped at random)."""
    sets = [s for s in SHORT if s != "--set"]
    sim = simulate(load_config("sca_acc_fusion", sets).simulation)
    flip = np.random.default_rng(0).choice([-1.0, 1.0], (sim.sca_q.shape[0], 1))
    sca = write_csv(
        tmp_path / "sca.csv",
        ["t_s", "q_x", "q_y", "q_z", "q_w", "note"],
        [[*row, "x"] for row in np.column_stack([sim.sca_t, sim.sca_q * flip]).tolist()],
    )
    acc = write_csv(
        tmp_path / "acc.csv", ["t_s", "dw_x", "dw_y", "dw_z"], np.column_stack([sim.acc_t, sim.acc])
    )
    return sca, acc


def test_data_files_give_the_simulation_result(simulated: Path, tmp_path: Path) -> None:
    sca, acc = simulated_files(tmp_path)
    out = tmp_path / "files"
    code, text = invoke("sca_acc_fusion", "--sca", str(sca), "--acc", str(acc), "--out", str(out))
    assert code == 0, text
    mine = np.array([[float(v) for v in r.values()] for r in read(out / "fused.csv")])
    ref = np.array([[float(v) for v in r.values()] for r in read(simulated / "fused.csv")])
    sign = np.sign(np.sum(mine[:, 1:5] * ref[:, 1:5], axis=1))[:, None]
    # the same solution up to rounding (the file quaternions are renormalised; sigmas ~1e-6 rad)
    np.testing.assert_allclose(mine[:, 1:5] * sign, ref[:, 1:5], atol=1e-10)
    np.testing.assert_allclose(mine[:, 5:], ref[:, 5:], rtol=1e-6)
    assert "Against the simulated truth" not in (out / "summary.md").read_text()


def corrupt(path: Path, row: int, column: str, value: str) -> None:
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    fields = lines[row].split(",")
    fields[header.index(column)] = value
    lines[row] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    ("which", "row", "column", "value", "message"),
    [
        ("sca", 7, "q_w", "nan", "row 7 (line 8), column q_w: non-finite"),
        ("acc", 12, "dw_y", "inf", "row 12 (line 13), column dw_y: non-finite"),
        ("acc", 3, "dw_x", "abc", "row 3 (line 4), column dw_x: 'abc' is not a number"),
        ("sca", 20, "t_s", "5.0", "row 20 (line 21), column t_s: time 5.0 does not increase"),
        ("sca", 9, "q_x", "0.5", "row 9 (line 10), columns q_x, q_y, q_z, q_w: quaternion norm"),
    ],
)
def test_bad_data_refused_with_file_row_column(
    tmp_path: Path, which: str, row: int, column: str, value: str, message: str
) -> None:
    sca, acc = simulated_files(tmp_path)
    target = sca if which == "sca" else acc
    corrupt(target, row, column, value)
    out = tmp_path / "out"
    code, text = invoke("sca_acc_fusion", "--sca", str(sca), "--acc", str(acc), "--out", str(out))
    flat = " ".join(text.split())
    assert code == 2, text
    assert str(target) in flat.replace("\n", "") or target.name in flat
    assert message in flat
    assert not out.exists()


def test_missing_column_and_other_bad_input(tmp_path: Path) -> None:
    sca, acc = simulated_files(tmp_path)
    out = tmp_path / "out"
    lines = acc.read_text().splitlines()
    acc.write_text("\n".join(line.rsplit(",", 1)[0] for line in lines) + "\n")  # drop dw_z
    code, text = invoke("sca_acc_fusion", "--sca", str(sca), "--acc", str(acc), "--out", str(out))
    assert code == 2 and "missing column dw_z" in " ".join(text.split())
    assert not out.exists()  # nothing written
    code, text = invoke("sca_acc_fusion", "--sca", str(sca), "--out", str(out))
    assert code == 2 and "both --sca and --acc" in text
    code, text = invoke("sca_acc_fusion", "--set", "estimator.huber=-1", "--out", str(out))
    assert code == 2 and "estimator.huber" in text
    code, text = invoke("no_such_preset", "--out", str(out))
    assert code == 2
    assert not out.exists()
