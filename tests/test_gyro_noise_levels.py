"""Noise levels drawn per episode (``scenario.onset.drift_scale``, ``noise_factor``) and the
gyro families (docs/redundant_gyros.md, "Noise levels", "Gyro families")."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from qkf.core.config import ConfigError
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.episodes import EpisodeSampler
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import simulate_run
from qkf.redundant_gyros.scenario import draw_onset, epochs, onset_generator
from qkf.redundant_gyros.ukf import triad_rate

FAMILY = "gyro_noise_levels"
SHORT = ["scenario.duration_s=60"]


def _sim(*overrides: str, seed: int = 11):  # type: ignore[no-untyped-def]
    cfg = load_config(FAMILY, [*SHORT, *overrides])
    return cfg, simulate_run(cfg, seed=seed)


def test_factors_of_one_reproduce_the_run_without_them() -> None:
    """Drawing a factor of exactly 1 changes nothing: the draws come after the others, from
    the same stream, and the noise has its own stream."""
    _, none = _sim("scenario.onset.drift_scale=null", "scenario.onset.noise_factor=null")
    _, ones = _sim("scenario.onset.drift_scale=[1,1]", "scenario.onset.noise_factor=[1,1]")
    assert np.array_equal(none.meas, ones.meas) and np.array_equal(none.coeffs, ones.coeffs)


def test_drift_scale_multiplies_the_walk() -> None:
    _, base = _sim("scenario.onset.drift_scale=[1,1]")
    _, three = _sim("scenario.onset.drift_scale=[3,3]")
    assert base.coeffs is not None and three.coeffs is not None
    g = 3  # S
    walk1 = base.coeffs[0, :, g] - base.coeffs[0, 0, g]
    walk3 = three.coeffs[0, :, g] - three.coeffs[0, 0, g]
    assert np.max(np.abs(walk1)) > 0
    np.testing.assert_allclose(walk3, 3.0 * walk1, rtol=1e-9, atol=1e-300)


def test_noise_factor_scales_the_gyros_white_noise_only() -> None:
    """Same noise stream: the readings of S move by (f − 1) σ ε, the other gyros not at all."""
    args = ("scenario.onset.drift_scale=null",)
    _, one = _sim(*args, "scenario.onset.noise_factor=[1,1]")
    _, two = _sim(*args, "scenario.onset.noise_factor=[2,2]")
    _, four = _sim(*args, "scenario.onset.noise_factor=[4,4]")
    others = [0, 1, 2, 4]
    assert np.array_equal(one.meas[..., others], four.meas[..., others])
    d2, d4 = two.meas[0, :, 3] - one.meas[0, :, 3], four.meas[0, :, 3] - one.meas[0, :, 3]
    np.testing.assert_allclose(d4, 3.0 * d2, rtol=1e-6, atol=1e-15)
    assert np.std(d2) == pytest.approx(0.001, rel=0.05)  # (2 − 1) × the unit's 0.001 deg/s


def test_levels_are_log_uniform_in_their_ranges() -> None:
    cfg = load_config(FAMILY, SHORT)
    spec = cfg.scenario.onset
    assert spec is not None and spec.drift_scale is not None and spec.noise_factor is not None
    t = epochs(cfg.scenario.duration_s, cfg.scenario.dt_s)
    draws = [draw_onset(spec, t, onset_generator(7, k)) for k in range(400)]
    for bounds, values in (
        (spec.drift_scale, [d.drift_scale for d in draws]),
        (spec.noise_factor, [d.noise_factor for d in draws]),
    ):
        lo, hi = np.log(bounds)
        u = (np.log(values) - lo) / (hi - lo)
        assert np.all((u >= 0) & (u <= 1))
        assert stats.kstest(u, "uniform").pvalue > 1e-4  # a false failure 1 in 10,000 runs


def test_ranges_are_checked() -> None:
    with pytest.raises(ConfigError, match="drift_scale"):
        load_config(FAMILY, ["scenario.onset.drift_scale=[10,1]"])
    with pytest.raises(ConfigError, match="noise_factor"):
        load_config(FAMILY, ["scenario.onset.noise_factor=[0,1]"])


@pytest.mark.parametrize(
    "family", [FAMILY, "gyro_shift_noise_levels", "gyro_control", "gyro_mixture"]
)
def test_sampler_episodes_are_the_simulations(family: str) -> None:
    cfg = load_config(family, SHORT)
    sampler = EpisodeSampler(cfg)
    unit, s, g = build_unit(cfg), sampler.target.start, sampler.setup.gyro
    # seeds 3 … 10 draw every component of the mixture (tests/test_gyro_mixture.py)
    for seed in range(3, 11):
        ep = sampler.draw(seed)
        d = simulate_run(cfg, seed=seed)
        truth = d.trial_coeffs(0)
        assert truth is not None
        assert np.array_equal(ep.truth, truth[s:, g])
        np.testing.assert_allclose(ep.z, d.meas[0, s:, g], rtol=0, atol=1e-12)
        ref_rate = triad_rate(unit, sampler.setup, d.meas[0, s:])
        np.testing.assert_allclose(ep.rate, ref_rate, rtol=0, atol=1e-12)


def test_the_shift_group_lies_outside_the_training_family() -> None:
    train = load_config(FAMILY).scenario.onset
    shift = load_config("gyro_shift_noise_levels").scenario.onset
    assert train is not None and shift is not None
    assert train.drift_scale is not None and shift.drift_scale is not None
    assert train.noise_factor is not None and shift.noise_factor is not None
    assert shift.drift_scale[0] >= train.drift_scale[1]
    assert shift.noise_factor[0] >= train.noise_factor[1]
