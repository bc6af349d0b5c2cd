"""The gyro training mixture (``scenario.onset_mixture``, ``configs/redundant_gyros/
gyro_mixture.yaml``; docs/redundant_gyros.md, "Gyro families"): each component is its preset's
onset, an episode is the episode of the same seed of the family it drew, the draw is uniform
(the fast sampler equals the simulation: tests/test_gyro_noise_levels.py), and a bad mixture is
refused on load."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from qkf.core.config import ConfigError
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.hindsight import env_draw, episode
from qkf.redundant_gyros.methods import GYRO_METHODS, with_mixture
from qkf.redundant_gyros.problem import CONTROL_FAMILIES, FAMILIES, PROBLEM, SHIFT_FAMILIES
from qkf.redundant_gyros.scenario import mixture_component

MIXTURE = "gyro_mixture"
SHORT = ["scenario.duration_s=160"]


def test_each_component_is_its_preset_and_the_shift_group_is_not_one() -> None:
    mix = load_config(MIXTURE).scenario.onset_mixture
    assert mix is not None
    names = [c.name for c in mix]
    assert set(names) == {*FAMILIES, *CONTROL_FAMILIES} - {MIXTURE}
    assert not set(names) & set(SHIFT_FAMILIES)
    mixed, base = load_config(MIXTURE), load_config("gyro_noise_levels")
    for c in mix:
        preset = load_config(c.name)
        assert c.onset == preset.scenario.onset, c.name
        # everything but the scenario's onset (and the name) is the preset's
        assert mixed.calibration == preset.calibration and mixed.unit == preset.unit, c.name
    assert mixed.environment == base.environment
    assert PROBLEM.families.mixture == MIXTURE and MIXTURE in PROBLEM.families.judged


def test_an_episode_is_the_same_seeds_episode_of_the_family_it_drew() -> None:
    cfg = load_config(MIXTURE, SHORT)
    mix = cfg.scenario.onset_mixture
    assert mix is not None
    presets = {c.name: load_config(c.name, SHORT) for c in mix}
    seen = set()
    for seed in range(5_000_000, 5_000_012):
        i = mixture_component(cfg.scenario, env_draw(seed), 0)
        assert i is not None
        seen.add(mix[i].name)
        ep, own = episode(cfg, seed), episode(presets[mix[i].name], seed)
        assert np.array_equal(ep.inputs.z, own.inputs.z), (seed, mix[i].name)
        assert np.array_equal(ep.inputs.truth, own.inputs.truth)
        assert ep.inputs.onset_s == own.inputs.onset_s
    assert seen == set(presets)  # 12 episodes drew every family


def test_the_family_is_drawn_uniformly() -> None:
    sc = load_config(MIXTURE).scenario
    draws = [mixture_component(sc, seed, 0) for seed in range(3000)]
    counts = np.bincount(np.asarray(draws), minlength=3)
    assert stats.chisquare(counts).pvalue > 1e-3, counts
    # and apart from the trial: trial 1 of a seed draws again
    assert [mixture_component(sc, 7, t) for t in range(40)] != [draws[7]] * 40


def test_seeds_3_to_10_draw_every_component() -> None:
    """What tests/test_gyro_noise_levels.py's sampler-equals-simulation check relies on."""
    sc = load_config(MIXTURE).scenario
    assert {mixture_component(sc, seed, 0) for seed in range(3, 11)} == {0, 1, 2}


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["scenario.onset={gyro: S, onset_s: [1, 2]}"], "cannot stand next to onset"),
        (["scenario.onset_mixture.1.name=gyro_noise_levels"], "gyro_noise_levels named twice"),
        (["scenario.onset_mixture.1.onset.gyro=T"], "one gyro for all"),
        ([f"scenario.onset_mixture.{i}.onset.gyro=Q" for i in range(3)], "unknown gyro .Q."),
    ],
)
def test_a_bad_mixture_is_refused_on_load(overrides: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(MIXTURE, overrides)


def test_the_mixed_methods_tune_on_the_mixture_in_the_judged_config() -> None:
    """``constant-mixed`` is ``constant`` given the tuning episodes of the judged config with the
    mixture's onsets (its duration and filter kept), whatever tuning episodes it is handed; on
    the mixture itself it is ``constant``."""
    cfg = load_config("gyro_shift_noise_levels", SHORT)
    mixed = with_mixture(cfg)
    assert mixed.scenario.onset is None and mixed.scenario.duration_s == 160
    assert mixed.scenario.onset_mixture == load_config(MIXTURE).scenario.onset_mixture
    assert mixed.calibration == cfg.calibration and mixed.environment == cfg.environment
    episodes = PROBLEM.simulate(cfg, 5_000_000, range(3))
    got = GYRO_METHODS["constant-mixed"](cfg, episodes, PROBLEM.tuning(cfg))
    want = GYRO_METHODS["constant"](cfg, episodes, PROBLEM.tuning(mixed))
    np.testing.assert_array_equal(got, want)
    own = GYRO_METHODS["constant"](cfg, episodes, PROBLEM.tuning(cfg))
    assert not np.array_equal(got, own)  # the shift's own best κ is another
    mix = load_config(MIXTURE, SHORT)
    on_mix = PROBLEM.simulate(mix, 5_000_000, range(3))
    np.testing.assert_array_equal(
        GYRO_METHODS["clock-mixed"](mix, on_mix, []),
        GYRO_METHODS["clock"](mix, on_mix, PROBLEM.tuning(mix)),
    )
