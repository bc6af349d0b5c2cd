"""Redundant-gyro fault detection and isolation: false-alarm rates against the configured
probability, the GLT's detection probability against the noncentral χ², 8σ faults on every gyro,
the paper's two scenarios, and the metric counting."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.config import Fault
from qkf.redundant_gyros.fdi import Detectors, run_fdi
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.metrics import count_trials
from qkf.redundant_gyros.parity import GltDetector
from qkf.redundant_gyros.scenario import epochs, first_epoch, simulate
from qkf.redundant_gyros.threecross import NO_GYRO, window_sums


@pytest.fixture(scope="module")
def no_fault_readings() -> tuple[object, np.ndarray]:
    """10⁶ fault-free epochs (100 trials × 10⁴), compensated."""
    cfg = load_config("five_gyros")
    unit = build_unit(cfg)
    t = epochs(1000.0, 0.1)
    data = simulate(unit, cfg.scenario.body_rate, [], t, 11, range(100))
    return unit, unit.compensate(data.meas)


@pytest.mark.parametrize("p_fa", [1e-3, 1e-2])
@pytest.mark.parametrize("window", [1, 25])
def test_no_fault_false_alarm_rate_matches_the_configured_probability(
    no_fault_readings: tuple[object, np.ndarray], p_fa: float, window: int
) -> None:
    unit, y = no_fault_readings
    res = GltDetector(unit, window, p_fa).test(y)  # type: ignore[arg-type]
    rate = res.detected[:, window - 1 :].mean()
    assert y.shape[0] * y.shape[1] >= 100_000
    assert abs(rate / p_fa - 1.0) < 0.2, rate


def test_three_cross_false_alarm_rate_stays_below_the_configured_probability(
    no_fault_readings: tuple[object, np.ndarray],
) -> None:
    unit, y = no_fault_readings
    det = Detectors.build(unit, load_config("five_gyros").fdi)  # type: ignore[arg-type]
    _, iso = det.threecross.isolate(y)
    rate = (iso[:, det.threecross.window - 1 :] != NO_GYRO).mean()
    assert rate < 1.2e-3  # binomial quantile at P_FA / n per gyro: conservative by design


def _step_faults(size_sigma: float, trials: int, seed: int) -> list[tuple[int, np.ndarray]]:
    cfg = load_config("five_gyros")
    unit = build_unit(cfg)
    t = epochs(60.0, 0.1)
    out = []
    for i, gid in enumerate(unit.ids):
        fault = Fault(gyro=gid, t_s=30.0, kind="bias_step", size=size_sigma * unit.noise[i])
        data = simulate(unit, cfg.scenario.body_rate, [fault], t, seed, range(trials))
        out.append((i, unit.compensate(data.meas)))
    return out


def test_per_epoch_glt_detection_follows_the_noncentral_chi_square() -> None:
    """A bias step f on gyro i shifts the whitened parity by f v_i / s_i, so pᵀp is noncentral
    χ²(n − 3, (f ‖v_i‖ / s_i)²): the detection rate after the fault must match it."""
    cfg = load_config("five_gyros")
    unit = build_unit(cfg)
    det = GltDetector(unit, 1, 1e-3)
    thr = stats.chi2.ppf(1 - 1e-3, unit.n - 3)
    for i, y in _step_faults(4.0, 100, 3):
        rate = det.test(y).detected[:, 300:].mean()
        nc = (4.0 * unit.noise[i] * np.linalg.norm(unit.v_parity[:, i]) / unit.comp_noise[i]) ** 2
        expected = stats.ncx2.sf(thr, unit.n - 3, nc)
        sd = np.sqrt(expected * (1 - expected) / y[:, 300:].size)
        assert abs(rate - expected) < 5 * sd + 1e-3, (unit.ids[i], rate, expected)


def test_8_sigma_steps_on_every_gyro_are_detected_and_isolated_by_the_windowed_glt() -> None:
    """The default GLT (25-epoch window): ≥ 99 % of post-fault epochs detected and ≥ 95 %
    isolated correctly, from the first full window after the fault on. (The per-epoch GLT
    cannot do this with this geometry: X/Y and Z/S parity columns are 14° and 21° apart.)"""
    cfg = load_config("five_gyros")
    unit = build_unit(cfg)
    det = GltDetector(unit, cfg.fdi.glt_window_epochs, cfg.fdi.false_alarm_probability)
    assert det.window == 25
    for i, y in _step_faults(8.0, 100, 5):
        res = det.test(y)
        post = slice(300 + det.window - 1, None)
        detected = res.detected[:, post].mean()
        correct = (res.isolated[:, post] == i).mean()
        assert detected >= 0.99, (unit.ids[i], detected)
        assert correct >= 0.95, (unit.ids[i], correct)


def test_large_steps_on_every_gyro_are_isolated_by_three_cross() -> None:
    cfg = load_config("five_gyros")
    unit = build_unit(cfg)
    det = Detectors.build(unit, cfg.fdi)
    for i, y in _step_faults(100.0, 20, 9):
        _, iso = det.threecross.isolate(y)
        post = slice(300 + det.threecross.window - 1, None)
        assert (iso[:, post] == i).mean() >= 0.95, unit.ids[i]
        assert (iso[:, 49:300] != NO_GYRO).mean() < 0.01


@pytest.mark.parametrize(
    ("preset", "gyro", "model"),
    [("five_gyros_y_misalignment", "Y", "XST"), ("five_gyros_s_bias", "S", "XYZ")],
)
def test_the_paper_scenarios_isolate_the_faulty_gyro(preset: str, gyro: str, model: str) -> None:
    cfg = load_config(preset, ["scenario.duration_s=180"])
    unit = build_unit(cfg)
    det = Detectors.build(unit, cfg.fdi)
    t = epochs(cfg.scenario.duration_s, cfg.scenario.dt_s)
    data = simulate(unit, cfg.scenario.body_rate, cfg.scenario.faults, t, 2, range(10))
    res = run_fdi(det, data.meas)
    k0 = first_epoch(t, cfg.scenario.faults[0].t_s)
    settled = slice(k0 + det.threecross.window, None)
    i = unit.index(gyro)
    assert (res.isolated_threecross[:, settled] == i).mean() >= 0.95
    assert (res.glt.isolated[:, settled] == i).mean() >= 0.99
    names = np.array(det.model_names)[res.model[:, settled]]
    assert (names == model).mean() >= 0.95
    # the reconstructed rate leaves the faulty gyro out: its error is noise-sized
    assert data.rate is not None
    err = res.rate[:, settled] - data.rate[settled]
    assert np.sqrt(np.mean(err**2)) < 5 * unit.noise.max()
    # before the fault: the fusion of the three models, equally noise-sized
    before = res.rate[:, : k0 - det.threecross.window] - data.rate[: k0 - det.threecross.window]
    assert np.sqrt(np.mean(before**2)) < 5 * unit.noise.max()


def test_window_sums_against_a_loop() -> None:
    x = np.random.default_rng(0).integers(0, 5, (3, 40)).astype(float)
    for window in (1, 4, 40, 60):
        expected = np.array(
            [[x[b, max(0, k - window + 1) : k + 1].sum() for k in range(40)] for b in range(3)]
        )
        np.testing.assert_array_equal(window_sums(x, window), expected)


def test_trial_counts_by_hand() -> None:
    iso = np.full((2, 10), NO_GYRO, dtype=np.int16)
    iso[0, 0] = 3  # a false alarm before the first full window: not counted
    iso[0, 3] = 2  # a false alarm counted
    iso[0, 6:] = [1, 1, 2, 1]  # fault at epoch 5 on gyro 1, window 2: counted from epoch 6
    iso[1, 9] = 1
    c = count_trials(iso, faulty=1, fault_epoch=5, window=2, dt=0.5)
    np.testing.assert_array_equal(c.pre_epochs, [4, 4])  # epochs 1 … 4
    np.testing.assert_array_equal(c.false_alarms, [1, 0])
    np.testing.assert_array_equal(c.post_epochs, [4, 4])  # epochs 6 … 9
    np.testing.assert_array_equal(c.detected, [4, 1])
    np.testing.assert_array_equal(c.correct, [3, 1])
    np.testing.assert_array_equal(c.delay_s, [0.5, 2.0])
