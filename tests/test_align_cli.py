"""``qkf align``: the output contract, a data file giving the result of the simulation it came
from, the observability report, and bad input refused with file, row and column (exit 2,
nothing written)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app

COLUMNS = [
    "sensor",
    "theta_x_urad",
    "theta_y_urad",
    "theta_z_urad",
    "sd_x_urad",
    "sd_y_urad",
    "sd_z_urad",
]
SHORT = ["--set", "simulation.epochs=120"]


def invoke(*args: str) -> tuple[int, str]:
    res = CliRunner().invoke(app, ["align", *args])
    return res.exit_code, res.output


def read(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("align") / "sim"
    code, text = invoke("alignment_three_sensors", *SHORT, "--out", str(out))
    assert code == 0, text
    return out


@pytest.mark.figures
def test_outputs_follow_the_contract(simulated: Path) -> None:
    names = {p.name for p in simulated.iterdir()}
    assert {
        "alignment.csv",
        "observability.csv",
        "summary.md",
        "residuals.png",
        "data.csv",
    } <= names
    with (simulated / "alignment.csv").open() as f:
        assert next(csv.reader(f)) == COLUMNS
    rows = read(simulated / "alignment.csv")
    assert [r["sensor"] for r in rows] == ["st1", "st2", "sun"]
    ref = rows[0]
    assert all(float(ref[c]) == 0.0 for c in COLUMNS[1:])
    for r in rows[1:]:
        assert all(float(r[c]) > 0.0 for c in COLUMNS[4:])
    # the preset's true st2 x-alignment is 0.8° = 13963 µrad
    assert float(rows[1]["theta_x_urad"]) == pytest.approx(0.8 * np.pi / 180 * 1e6, abs=10.0)
    text = (simulated / "summary.md").read_text()
    for part in (
        "## Observability",
        "Rank of the data information: **6 of 6**",
        "## Residuals",
        "## Errors against the simulated truth",
        "NEES",
    ):
        assert part in text, part
    assert len(read(simulated / "observability.csv")) == 6


def test_data_file_gives_the_result_of_its_simulation(simulated: Path, tmp_path: Path) -> None:
    out = tmp_path / "from_data"
    code, text = invoke(
        "alignment_three_sensors", "--data", str(simulated / "data.csv"), "--out", str(out)
    )
    assert code == 0, text
    a = read(simulated / "alignment.csv")
    b = read(out / "alignment.csv")
    for ra, rb in zip(a, b, strict=True):
        for c in COLUMNS[1:]:
            assert float(rb[c]) == pytest.approx(float(ra[c]), rel=1e-9, abs=1e-9)
    text = (out / "summary.md").read_text()
    assert "Errors against the simulated truth" not in text
    assert not (out / "data.csv").exists()


def test_unobservable_direction_is_flagged(tmp_path: Path) -> None:
    out = tmp_path / "two"
    sensors = (
        "sensors=[{name: ref, sigma_arcsec: 5, boresight: [0, 0, 1], fov_deg: 0},"
        " {name: st, sigma_arcsec: 5, boresight: [1, 0, 0], fov_deg: 10}]"
    )
    code, text = invoke(
        "alignment_three_sensors",
        *SHORT,
        "--set",
        sensors,
        "--set",
        "reference=ref",
        "--out",
        str(out),
    )
    assert code == 0, text
    summary = (out / "summary.md").read_text()
    assert "**2 of 3**" in summary
    assert "- rank-deficient and prior-determined: st about body axis [" in summary
    rows = read(out / "observability.csv")
    flagged = [r for r in rows if r["prior_determined"] == "true"]
    assert len(flagged) == 1 and flagged[0]["rank_deficient"] == "true"
    assert abs(float(flagged[0]["st_z"])) > 0.999


def _write(path: Path, header: list[str], rows: list[list[object]]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    return path


HEADER = ["t_s", "sensor", "w_x", "w_y", "w_z", "r_x", "r_y", "r_z"]
GOOD = [
    [0.0, "st1", 0, 0, 1, 1, 0, 0],
    [0.0, "st2", 0, 1, 0, 0, 1, 0],
    [0.0, "sun", 1, 0, 0, 0, 0, 1],
    [1.0, "st1", 0, 0.6, 0.8, 0.6, 0.8, 0],
    [1.0, "st2", 0.8, 0.6, 0, 0, 0.6, 0.8],
]


@pytest.mark.parametrize(
    ("edit", "expect"),
    [
        (lambda h, r: (h[:-1], [x[:-1] for x in r]), ["missing column r_z"]),
        (
            lambda h, r: (h, [*r[:2], [0.0, "star9", 1, 0, 0, 1, 0, 0], *r[3:]]),
            ["row 3 (line 4)", "column sensor", "star9"],
        ),
        (
            lambda h, r: (h, [*r[:3], [1.0, "st1", 0, 0.6, "nan", 0.6, 0.8, 0], r[4]]),
            ["row 4 (line 5)", "column w_z", "non-finite"],
        ),
        (
            lambda h, r: (h, [*r[:1], [0.0, "st2", 0, 1.01, 0, 0, 1, 0], *r[2:]]),
            ["row 2 (line 3)", "columns w_x, w_y, w_z", "not a unit vector"],
        ),
        (
            lambda h, r: (h, [*r[:4], [1.0, "st2", 0.8, 0.6, 0, 0, 0.6, "x"]]),
            ["row 5 (line 6)", "column r_z", "not a number"],
        ),
        (
            lambda h, r: (h, [*r[:2], [0.5, "sun", 1, 0, 0, 0, 0, 1], *r[3:]]),
            ["never paired", "'sun'"],
        ),
    ],
    ids=[
        "missing-column",
        "unknown-sensor",
        "non-finite",
        "non-unit",
        "not-a-number",
        "never-paired",
    ],
)
def test_bad_data_is_refused_naming_file_row_and_column(edit, expect, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    header, rows = edit(list(HEADER), [list(r) for r in GOOD])
    data = _write(tmp_path / "data.csv", header, rows)
    out = tmp_path / "out"
    code, text = invoke("alignment_three_sensors", "--data", str(data), "--out", str(out))
    assert code == 2, text
    flat = " ".join(text.split())
    assert str(data) in flat.replace(" ", "") or "data.csv" in flat
    for part in expect:
        assert part in flat, (part, flat)
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_good_small_file_runs(tmp_path: Path) -> None:
    data = _write(tmp_path / "data.csv", HEADER, GOOD)
    code, text = invoke(
        "alignment_three_sensors", "--data", str(data), "--out", str(tmp_path / "out"), "--no-plot"
    )
    assert code == 0, text
    # two epochs cannot determine six angles: the report says so
    assert "not determined by the data" in (tmp_path / "out" / "summary.md").read_text()


@pytest.mark.parametrize(
    ("sets", "expect"),
    [
        (["reference=nope"], "reference"),
        (["sensors.1.name=st1"], "unique"),
        (["sensors.0.misalignment_deg=[0.1, 0, 0]"], "reference"),
        (["prior_deg=-1"], "prior_deg"),
        (["simulation.epochs=0"], "simulation.epochs"),
    ],
)
def test_bad_config_is_refused(sets: list[str], expect: str, tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = [x for s in sets for x in ("--set", s)]
    code, text = invoke("alignment_three_sensors", *args, "--out", str(out))
    assert code == 2, text
    assert expect in " ".join(text.split())
    assert not out.exists()
