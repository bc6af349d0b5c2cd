"""What a user sees (issue 18): the progress bar moves for small runs and shows tuning as its own
row, figures keep their legends off the data and say what they plot, summary.md describes the
settled window it really used, studies refuse ambiguous labels, take presets, --trials and --set,
and `qkf plot` redraws studies and refuses bad folders cleanly."""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rich.console import Console
from rich.progress import Progress
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core import montecarlo
from qkf.core.config import ConfigError
from qkf.core.montecarlo import progress_bar
from qkf.transfer_alignment.bench_figures import kappa_figure, rms_groups_figure, rms_states_figure
from qkf.transfer_alignment.benchmark import BenchResult, run_benchmark
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.methods.base import action_values
from qkf.transfer_alignment.methods.oracle import tune_oracle
from qkf.transfer_alignment.metrics import GROUPS, state_errors
from qkf.transfer_alignment.report import summary_markdown
from qkf.transfer_alignment.scenario import simulate
from qkf.transfer_alignment.states import DISPLAY_UNIT
from qkf.transfer_alignment.study import load_study
from qkf.transfer_alignment.study_figures import study_figure
from tests.conftest import CONFIGS

runner = CliRunner()


def _refused(result: Any, *needles: str) -> None:
    out = result.output
    assert result.exit_code == 2, out
    assert "Traceback" not in out and out.count("error:") == 1, out
    for needle in needles:
        assert needle in out, out


# ---- progress ----------------------------------------------------------------------------------


class RecordingProgress(Progress):
    """A rich Progress on an 80-column console that records every task's state after each
    update (what the user would see move)."""

    last: RecordingProgress | None = None

    def __init__(self, *columns: Any, **kwargs: Any) -> None:
        kwargs["console"] = Console(width=80, file=io.StringIO(), force_terminal=True)
        kwargs["disable"] = False
        super().__init__(*columns, **kwargs)
        self.seen: list[tuple[str, float, float | None]] = []
        RecordingProgress.last = self

    def update(self, task_id: Any, **kwargs: Any) -> None:
        super().update(task_id, **kwargs)
        task = self._tasks[task_id]
        self.seen.append((task.description, task.completed, task.total))

    def completed(self, description: str) -> list[float]:
        return [c for d, c, _ in self.seen if d == description]

    def screen(self) -> list[str]:
        con = Console(width=80, record=True, file=io.StringIO(), color_system=None)
        con.print(self.get_renderable())
        return con.export_text().splitlines()


@pytest.fixture
def recorded(monkeypatch: pytest.MonkeyPatch) -> type[RecordingProgress]:
    monkeypatch.setattr(montecarlo, "Progress", RecordingProgress)
    return RecordingProgress


def test_progress_moves_within_one_chunk_and_tuning_has_its_own_row(
    recorded: type[RecordingProgress],
) -> None:
    cfg = load_config("paper", ["scenario.duration_s=40", "adaptive.tuned.trials=2"])
    run_benchmark(cfg, "kf,kf-tuned", trials=3, seed=0, progress=True)
    bar = recorded.last
    assert bar is not None
    # 3 trials are one chunk of 64: the bar still moves per method (2 methods × 3 trials)
    main = bar.completed("bench: 2 methods")
    assert 0 < main[-1] and 3.0 in main and main[-1] == 6.0, main
    tuning = [(c, t) for d, c, t in bar.seen if d == "tune kf-tuned"]
    n_actions = len(action_values(cfg))
    assert [c for c, _ in tuning] == list(range(1, n_actions + 1)) and tuning[-1][1] == n_actions


def test_progress_line_stays_readable_at_80_columns(recorded: type[RecordingProgress]) -> None:
    cfg = load_config("paper", ["scenario.duration_s=20"])
    long_labels = [f"a-rather-long-method-label-{i}=kf" for i in range(10)]
    run_benchmark(cfg, ",".join(long_labels), trials=2, seed=0, progress=True)
    assert recorded.last is not None
    lines = [line for line in recorded.last.screen() if line.strip()]
    assert len(lines) == 1, lines  # one row, not a label list wrapped over several
    assert lines[0].startswith("bench: 10 methods") and "100%" in lines[0], lines
    assert "2/2 trials" in lines[0] and len(lines[0]) <= 80, lines


def test_oracle_tuning_row_counts_every_run(recorded: type[RecordingProgress]) -> None:
    cfg = load_config(
        "thermal_snap",
        ["scenario.duration_s=60", "scenario.calibration_jumps.0.t_s=30",
         "adaptive.tuned.trials=2", "adaptive.oracle.windows_s=[10, 20]", "run.settled_s=10"],
    )  # fmt: skip
    with progress_bar(1, "t"):
        tune_oracle(cfg, progress_label="tune oracle")
    assert recorded.last is not None
    rows = [(c, t) for d, c, t in recorded.last.seen if d == "tune oracle"]
    k = len(action_values(cfg))
    # every κ_base, the constant κ_base once more, every (κ_after ≠ κ_base, W): declared = done
    assert rows[-1] == (k + 1 + (k - 1) * 2, k + 1 + (k - 1) * 2), rows


def test_tuning_outside_a_run_shows_nothing() -> None:
    advance = montecarlo.progress_stage("tune x", 3)
    advance(1)  # no bar open: a no-op, not an error


# ---- figures -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def many() -> BenchResult:
    """Ten methods (seven of them kf under other labels: cheap) on a short run."""
    cfg = load_config("paper", ["scenario.duration_s=60"])
    specs = ["kf", "qkf", "sage-husa", *(f"kf{i}=kf" for i in range(7))]
    return run_benchmark(cfg, specs, trials=2, seed=0, progress=False)


def _legend_off_the_data(fig: Any) -> None:
    fig.canvas.draw()
    assert len(fig.legends) == 1
    box = fig.legends[0].get_window_extent()
    for ax in fig.axes:
        if ax.get_visible():
            assert not box.overlaps(ax.get_window_extent()), ax.get_title()
    assert not [ax for ax in fig.axes if ax.get_legend() is not None]


def test_rms_groups_legend_is_outside_every_panel(many: BenchResult) -> None:
    fig = rms_groups_figure(many)
    _legend_off_the_data(fig)
    assert len(fig.legends[0].get_texts()) == 11  # ten methods and the CRLB


def test_rms_states_have_human_titles_and_axis_labels(many: BenchResult) -> None:
    fig = rms_states_figure(many)
    _legend_off_the_data(fig)
    titles = [ax.get_title() for ax in fig.axes]
    assert titles[0] == "attitude x" and titles[3] == "gyro bias x"
    assert titles[6] == "scale factor s_x" and titles[9] == "misalignment k_xy"
    assert not [t for t in titles if "_arcsec" in t or "_urad" in t]
    assert fig.axes[0].get_ylabel() == "RMS [arcsec]" and fig.axes[9].get_ylabel() == "RMS [µrad]"
    assert all(ax.get_xlabel() == "time [s]" for ax in fig.axes[12:])


def test_kappa_gets_one_panel_per_adaptive_method(many: BenchResult) -> None:
    fig = kappa_figure(many)
    assert fig is not None
    shown = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert shown == [m.name for m in many.methods if m.kappa is not None] == ["qkf", "sage-husa"]


# ---- summary.md --------------------------------------------------------------------------------


def test_settled_text_of_a_run_shorter_than_settled_s() -> None:
    cfg = load_config("paper", ["scenario.duration_s=300"])  # run.settled_s: 400
    res = run_benchmark(cfg, "kf", trials=2, seed=0, progress=False)
    text = summary_markdown(res)
    assert "from 400 s on" not in text
    assert "*settled* = the last epoch only (t = 299 s), because the run ends before" in text
    assert "covariance, at the last sampled epoch only (t = 290 s;" in text  # every 10 s
    # what the text says is what was computed: the settled value is the last epoch's RMS
    data = simulate(cfg, 0, 2)
    from qkf.transfer_alignment.methods import METHODS

    err = state_errors(METHODS["kf"](cfg, data).est, data.q_true, data.bias, data.calib)
    last = (err[:, -1] / DISPLAY_UNIT)[:, GROUPS["att_arcsec"]]
    expected = np.sqrt(np.mean(np.mean(last**2, axis=1)))
    assert res.methods[0].summary["att_arcsec_settled"] == pytest.approx(expected, rel=1e-12)


def test_settled_text_of_a_long_run_says_each_trial_has_its_window() -> None:
    cfg = load_config("paper", ["scenario.duration_s=450"])
    res = run_benchmark(cfg, "kf", trials=2, seed=0, progress=False)
    text = summary_markdown(res)
    assert "*settled* = each trial's own window, from the later of 400 s and the first" in text
    assert "within 2 × its end-of-run value" in text


# ---- studies -----------------------------------------------------------------------------------


def _study(folder: Path, body: str, base: str = "paper", trials: int = 5) -> Path:
    path = folder / "s.yaml"
    path.write_text(f"name: s\nbase: {base}\nmethods: [kf]\ntrials: {trials}\n" + body)
    return path


def test_duplicate_labels_are_refused(tmp_path: Path) -> None:
    path = _study(tmp_path, "cases:\n  - {label: a}\n  - {label: b}\n  - {label: a}\n")
    with pytest.raises(ConfigError, match=r"cases\.2\.label: 'a' is also the label of cases\.0"):
        load_study(path)
    result = runner.invoke(app, ["study", str(path), "--out", str(tmp_path / "o")])
    _refused(result, str(path), "cases.2.label", "'a'")
    assert not (tmp_path / "o").exists()


def test_labels_that_give_one_folder_are_refused(tmp_path: Path) -> None:
    path = _study(tmp_path, "cases:\n  - {label: 'x + y'}\n  - {label: 'x y'}\n")
    with pytest.raises(ConfigError, match=r"cases\.1\.label: 'x y' and cases\.0\.label 'x \+ y'"
                       r" give the same case folder 'x_y'"):  # fmt: skip
        load_study(path)


def test_base_takes_a_preset_name_and_a_local_file_wins(tmp_path: Path) -> None:
    path = _study(tmp_path, "cases:\n  - {label: a}\n  - {label: b, base: thermal-snap}\n")
    _, configs = load_study(path)
    assert configs[0].name == load_config("paper").name
    assert configs[1].scenario.calibration_jumps  # the thermal_snap preset
    # a file beside the study with a preset's name wins over the preset
    local = _study(tmp_path, "cases:\n  - {label: a, set: [scenario.duration_s=123]}\n",
                   base="paper.yaml")  # fmt: skip
    (tmp_path / "paper.yaml").write_text(
        (CONFIGS / "paper.yaml").read_text().replace("duration_s: 3600", "duration_s: 77")
    )
    _, configs = load_study(local, ["scenario.dt_s=0.5"])
    assert configs[0].scenario.duration_s == 123 and configs[0].scenario.dt_s == 0.5
    _, configs = load_study(_study(tmp_path, "cases:\n  - {label: a}\n", base="paper.yaml"))
    assert configs[0].scenario.duration_s == 77  # the file beside the study, not the preset
    missing = _study(tmp_path, "cases:\n  - {label: a}\n", base="no_such_preset")
    with pytest.raises(ConfigError, match=r"cases\.0 \(a\): .*no_such_preset"):
        load_study(missing)


def _case_manifest(out: Path, case: str) -> dict[str, Any]:
    return json.loads((out / case / "run.json").read_text())


@pytest.mark.slow  # four study runs (resumed and rerun)
def test_study_trials_and_set_are_used_recorded_and_resumed(tmp_path: Path) -> None:
    cases = (
        "cases:\n  - {label: short, set: [scenario.duration_s=20]}\n"
        "  - {label: 'also short', set: [scenario.duration_s=30]}\n"
    )
    path = _study(tmp_path, cases)
    out = tmp_path / "o"
    args = ["study", str(path), "--out", str(out), "--quiet"]
    first = runner.invoke(app, [*args, "--trials", "2", "--set", "scenario.dt_s=0.5"])
    assert first.exit_code == 0, first.output
    assert "case 1/2: short" in first.output and "case 2/2: also short" in first.output
    info = _case_manifest(out, "short")
    assert info["trials"] == 2 and info["config"]["scenario"]["dt_s"] == 0.5
    assert info["config"]["scenario"]["duration_s"] == 20  # the case's own set kept
    root = json.loads((out / "run.json").read_text())
    assert root["kind"] == "study" and root["trials"] == 2 and root["sets"] == ["scenario.dt_s=0.5"]
    with (out / "also_short" / "summary.csv").open() as f:
        assert next(csv.DictReader(f))["trials"] == "2"
    # resume with the same options keeps both; with other trials, a case is not "finished"
    same = runner.invoke(app, [*args, "--resume", "--trials", "2", "--set", "scenario.dt_s=0.5"])
    assert same.exit_code == 0 and same.output.count("finished earlier, kept") == 2, same.output
    other = runner.invoke(app, [*args, "--resume", "--set", "scenario.dt_s=0.5"])
    assert other.exit_code == 0 and "finished earlier" not in other.output, other.output
    assert _case_manifest(out, "short")["trials"] == 5  # the study's own trials
    changed = runner.invoke(app, [*args, "--resume"])  # without the --set: other configs
    assert changed.exit_code == 0 and "finished earlier" not in changed.output


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--trials", "0"], ["--trials must be between 1 and"]),
        (["--trials", "10000001"], ["--trials must be between 1 and"]),
        (["--set", "scenario.nosuch=1"], ["cases.0 (a)", "scenario.nosuch"]),
    ],
)
def test_bad_study_options_are_refused(tmp_path: Path, args: list[str], needles: list[str]) -> None:
    path = _study(tmp_path, "cases:\n  - {label: a, set: [scenario.duration_s=20]}\n")
    result = runner.invoke(app, ["study", str(path), "--out", str(tmp_path / "o"), *args])
    _refused(result, *needles)
    assert not (tmp_path / "o").exists()


def test_trials_of_a_crlb_study_are_refused(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["study", "rotation_duration", "--trials", "3", "--out", str(tmp_path / "o")]
    )
    _refused(result, "--trials", "CRLB study")


@pytest.mark.figures
def test_plot_redraws_a_study_without_rerunning(tmp_path: Path) -> None:
    cases = (
        "cases:\n  - {label: a, set: [scenario.duration_s=20]}\n"
        "  - {label: b, set: [scenario.duration_s=20, filter.matching=attitude]}\n"
    )
    path = _study(tmp_path, cases, trials=2)
    out = tmp_path / "o"
    assert runner.invoke(app, ["study", str(path), "--out", str(out), "--quiet"]).exit_code == 0
    figures = [out / "study.png", out / "a" / "rms_groups.png", out / "b" / "rms_states.png"]
    for fig in figures:
        fig.unlink()
    stamp = (out / "a" / "rms.csv").stat().st_mtime_ns
    result = runner.invoke(app, ["plot", str(out)])
    assert result.exit_code == 0, result.output
    assert all(f.read_bytes()[:4] == b"\x89PNG" for f in figures)
    assert (out / "a" / "rms.csv").stat().st_mtime_ns == stamp  # nothing rerun


@pytest.mark.figures
def test_plot_redraws_a_crlb_study(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("name: c\nkind: crlb\nbase: paper\ncases:\n"
                    "  - {label: one, set: [scenario.duration_s=50]}\n"
                    "  - {label: two, set: [scenario.duration_s=60]}\n")  # fmt: skip
    out = tmp_path / "o"
    assert runner.invoke(app, ["study", str(path), "--out", str(out), "--quiet"]).exit_code == 0
    (out / "study.png").unlink()
    result = runner.invoke(app, ["plot", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / "study.png").read_bytes()[:4] == b"\x89PNG"


def test_study_figures_keep_the_legend_off_and_say_what_they_plot(tmp_path: Path) -> None:
    from qkf.transfer_alignment.cases import CaseResult, CaseRun, case_rows
    from qkf.transfer_alignment.crlb import crlb
    from qkf.transfer_alignment.study import Case, Study
    from qkf.transfer_alignment.study_figures import study_curves

    cfg = load_config("paper", ["scenario.duration_s=30"])
    two = [Case(label="one"), Case(label="two")]
    bench = Study(name="b", base="paper", methods=["kf", "qkf"], trials=2, cases=two)
    res = run_benchmark(cfg, "kf,qkf", trials=2, seed=0, progress=False)
    results = [CaseResult(CaseRun(c.label, c.label, cfg), res.bound, res) for c in bench.cases]
    rows = [row for r in results for row in case_rows(r)]
    fig = study_figure(bench, study_curves(results), rows, 0.95)
    _legend_off_the_data(fig)
    assert "bootstrap" in fig.axes[-1].get_title()
    # a CRLB study plots a bound: no error bars, and the title says so
    bound = Study(name="c", kind="crlb", base="paper", cases=two)
    results = [CaseResult(CaseRun(c.label, c.label, cfg), crlb(cfg), None) for c in bound.cases]
    rows = [row for r in results for row in case_rows(r)]
    fig = study_figure(bound, study_curves(results), rows, 0.95)
    _legend_off_the_data(fig)
    title = fig.axes[-1].get_title()
    assert "bootstrap" not in title and "no error bars" in title and "CRLB" in title


# ---- qkf plot: bad folders ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def bench_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bench") / "run"
    args = ["--methods", "kf", "--trials", "2", "--quiet", "--set", "scenario.duration_s=20"]
    result = runner.invoke(app, ["bench", "paper", "--out", str(out), *args])
    assert result.exit_code == 0, result.output
    return out


def _copy(src: Path, dst: Path) -> Path:
    dst.mkdir()
    for p in src.iterdir():
        (dst / p.name).write_bytes(p.read_bytes())
    return dst


def test_plot_on_a_file_says_so(bench_dir: Path) -> None:
    _refused(runner.invoke(app, ["plot", str(bench_dir / "rms.csv")]),
             f"{bench_dir / 'rms.csv'}: is a file, not a results folder")  # fmt: skip


def test_plot_on_a_folder_without_results(tmp_path: Path) -> None:
    _refused(runner.invoke(app, ["plot", str(tmp_path)]), "no qkf bench results (rms.csv)")


@pytest.mark.figures
@pytest.mark.parametrize(
    ("damage", "needles"),
    [
        ("truncate", ["rms.csv: line 14:", "truncated"]),
        ("garble", ["rms.csv: line 5: att_y_arcsec: 'abc' is not a number"]),
        ("short", ["rms.csv: method kf: 19 rows where crlb.csv has 20 epochs"]),
    ],
)
def test_plot_on_a_damaged_rms_csv(
    bench_dir: Path, tmp_path: Path, damage: str, needles: list[str]
) -> None:
    run = _copy(bench_dir, tmp_path / "run")
    lines = (run / "rms.csv").read_text().splitlines(keepends=True)
    if damage == "truncate":  # cut in the middle of line 14, as a full disk would
        text = "".join(lines[:13]) + lines[13][:30]
    elif damage == "garble":
        cells = lines[4].split(",")
        cells[3] = "abc"
        text = "".join(lines[:4]) + ",".join(cells) + "".join(lines[5:])
    else:
        text = "".join(lines[:-1])
    (run / "rms.csv").write_text(text)
    before = (run / "rms_groups.png").read_bytes()
    _refused(runner.invoke(app, ["plot", str(run)]), str(run / "rms.csv"), *needles)
    assert (run / "rms_groups.png").read_bytes() == before


def test_plot_on_a_read_only_folder(
    bench_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = _copy(bench_dir, tmp_path / "run")
    os.chmod(run, 0o555)
    try:
        if os.geteuid() == 0:  # root writes anyway: make the folder refuse as a read-only mount
            real = tempfile.mkstemp

            def refuse(*args: Any, **kwargs: Any) -> Any:
                if Path(kwargs.get("dir", "")) == run:
                    raise PermissionError(13, "Permission denied")
                return real(*args, **kwargs)

            monkeypatch.setattr(tempfile, "mkstemp", refuse)
        _refused(runner.invoke(app, ["plot", str(run)]), f"{run}: no permission to write in {run}")
    finally:
        os.chmod(run, 0o755)


def test_plot_of_a_sweep_with_one_damaged_case_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "sw"
    args = ["--methods", "kf", "--trials", "2", "--quiet", "--set", "scenario.duration_s=20",
            "--set", "sweep.values=[1, 10]"]  # fmt: skip
    assert runner.invoke(app, ["bench", "noise_mismatch", "--out", str(out), *args]).exit_code == 0
    first, second = out / "attitude_sigma_arcsec=1", out / "attitude_sigma_arcsec=10"
    (second / "rms.csv").write_text((second / "rms.csv").read_text()[:-40])
    stamp = (first / "rms_groups.png").stat().st_mtime_ns
    _refused(runner.invoke(app, ["plot", str(out)]), str(second / "rms.csv"))
    assert (first / "rms_groups.png").stat().st_mtime_ns == stamp  # read all, then write
