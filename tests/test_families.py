"""Randomized scenario families (docs/models.md, "Scenario families").

Every family preset loads and simulates; a trial is the same alone or in a batch; the events
drawn per trial follow the documented distributions (goodness of fit over 10,000 draws of
``draw_events``, seeded, p > 1e-3); the mixture holds exactly the families' own events; the two
families that existed before keep the draws they had for a given (seed, trial).
"""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from qkf.core import units
from qkf.core.config import ConfigError
from qkf.transfer_alignment.config import Config, RandomEventParts, Scenario, load_config
from qkf.transfer_alignment.methods.oracle import schedule
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.problem import FAMILIES as ALL_FAMILIES
from qkf.transfer_alignment.scenario import (
    component_scenario,
    draw_events,
    draw_trial,
    family_names,
    simulate,
    trial_streams,
)

# the families of qkf study families: the mixture and the seven it draws from
PRESETS = ALL_FAMILIES
FAMILIES = tuple(f for f in ALL_FAMILIES if f != "mixed_random")
SEED = 5_000_000  # tests use seeds outside every benchmark range (docs/environment.md)
DRAWS = 10_000
P_MIN = 1e-3  # a fit is refused below this p-value (the draws are seeded: no flakiness)

# the event distributions of docs/models.md, "Scenario families": (low, high) per draw
Range = tuple[float, float]
JUMPS: dict[str, tuple[Range, Range, Range]] = {  # time s, misalignment µrad, scale factor ppm
    "thermal_snap_random": ((1200, 2700), (100, 300), (0, 100)),
    "small_snap_random": ((1200, 2700), (20, 60), (0, 20)),
    "early_snap_random": ((400, 1200), (100, 300), (0, 100)),
}
DOUBLE_T, DOUBLE_SEPARATION = (900.0, 2700.0), 600.0  # sizes as thermal_snap_random
ROTATION = {"rate_deg_s": (0.5, 1.5), "duration_s": (60.0, 150.0)}
DRIFT = {"start_s": (600.0, 2400.0), "duration_s": (300.0, 900.0), "sigma": (3e-7, 3e-6)}
ADS_ARCSEC = (3.0, 10.0)


@functools.cache
def _config(name: str) -> Config:
    return load_config(name)


@functools.cache
def _draws(name: str) -> tuple[tuple[Scenario, int | None], ...]:
    """10,000 trials' events of a preset, drawn in a row from one seeded generator."""
    rng = np.random.default_rng([SEED, PRESETS.index(name)])
    sc = _config(name).scenario
    return tuple(draw_trial(sc, rng) for _ in range(DRAWS))


def _uniform(x: np.ndarray | list[float], low: float, high: float) -> None:
    x = np.asarray(x)
    assert np.all((x >= low) & (x <= high))
    assert stats.kstest(x, stats.uniform(loc=low, scale=high - low).cdf).pvalue > P_MIN


def _balanced(signs: np.ndarray) -> None:
    """Each column's signs are ± with probability ½ (binomial test per term)."""
    for column in signs.T:
        positive = int(np.sum(column > 0))
        assert stats.binomtest(positive, column.size, 0.5).pvalue > P_MIN


def _jump_terms(scs: list[Scenario], index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (D,), scale factors (D, 3) and misalignments (D, 6) of jump ``index``."""
    jumps = [sc.calibration_jumps[index] for sc in scs]
    return (
        np.array([j.t_s for j in jumps]),
        np.array([j.scale_factor_ppm for j in jumps]),
        np.array([j.misalignment_urad for j in jumps]),
    )


def _sizes(sf: np.ndarray, ma: np.ndarray, sf_range: Range, ma_range: Range) -> None:
    for column in np.abs(sf).T:
        _uniform(column, *sf_range)
    for column in np.abs(ma).T:
        _uniform(column, *ma_range)
    _balanced(np.concatenate([sf, ma], axis=1))


# -- every preset ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", PRESETS)
def test_family_preset_simulates_and_repeats_per_trial(name: str) -> None:
    cfg = _config(name)
    sc = cfg.scenario
    # the shared base scenario, so that the mixture of the families is coherent
    assert sc.randomize_truth and sc.random_events is not None
    assert (sc.dt_s, sc.duration_s, sc.altitude_km) == (1.0, 3600.0, 700.0)
    assert sc.calibration_walk.sigma_per_sqrt_s == 1e-9
    assert (sc.ads.attitude_sigma_arcsec, sc.ads.rate_sigma_degph) == (3.0, 0.02)
    assert (sc.gyro.arw_deg_sqrt_h, sc.gyro.rrw_deg_h_1_5) == (4e-4, 1e-3)
    assert FilterParams.from_config(cfg).sigma_a == 3.0 * units.ARCSEC
    events: list[RandomEventParts] = [] if sc.random_events.mixture else [sc.random_events]
    events += [c.events for c in sc.random_events.mixture or []]
    assert all(e.maneuvers is not None for e in events)  # a random rotation schedule in all

    both = simulate(cfg, SEED, [0, 1])
    alone = simulate(cfg, SEED, [1])
    for field in ("gyro", "ads_q", "ads_rate", "bias", "calib", "q_true", "jumps_t"):
        np.testing.assert_array_equal(getattr(alone, field)[0], getattr(both, field)[1])
    assert np.all(np.isfinite(both.gyro)) and not np.array_equal(both.gyro[0], both.gyro[1])
    assert both.jumps_t is not None and both.jump_t is not None
    np.testing.assert_array_equal(both.jumps_t[:, 0], both.jump_t)  # NaN-equal too
    assert (both.family is not None) == (name == "mixed_random")
    if both.family is not None:
        assert alone.family is not None and alone.family[0] == both.family[1]
    draws_ads = name in ("ads_mismatch_random", "mixed_random")
    assert (both.ads_sigma_rad is not None) == draws_ads
    if both.ads_sigma_rad is not None:
        assert alone.ads_sigma_rad is not None
        assert alone.ads_sigma_rad[0] == both.ads_sigma_rad[1]


def test_mixed_trials_repeat_alone_across_their_families() -> None:
    cfg = _config("mixed_random")
    ids = list(range(12))
    batch = simulate(cfg, SEED + 1, ids)
    assert batch.family is not None and len(set(batch.family.tolist())) >= 4
    for trial in (0, 5, 11):
        one = simulate(cfg, SEED + 1, [trial])
        np.testing.assert_array_equal(one.gyro[0], batch.gyro[trial])
        np.testing.assert_array_equal(one.calib[0], batch.calib[trial])
        assert one.family is not None and one.family[0] == batch.family[trial]
    assert family_names(cfg) == FAMILIES
    assert family_names(_config("thermal_snap_random")) == ()


# -- the existing families keep their draws ----------------------------------------------------


def test_thermal_snap_random_draws_what_it_drew_before() -> None:
    """Trial 3 of seed 7000, as drawn before the families were extended (values recorded from
    that code): rotation sequence, jump time, sizes and signs, sequence after the jump."""
    sc = draw_events(_config("thermal_snap_random").scenario, trial_streams(7000, 3)["events"])
    axes = [m.axis for m in sc.maneuvers]
    assert axes == ["y", "z", "x", "z", "x", "y"]
    # The values below are uniform draws of numpy's Generator, signed and summed: correctly
    # rounded IEEE arithmetic only, bit for bit the same on every CPU, hence the tight 1e-13.
    np.testing.assert_allclose(
        [m.duration_s for m in sc.maneuvers],
        [
            *(148.10244032524807, 128.09372488639374, 100.32509121352987),
            *(143.81339336304535, 144.07217568763238, 131.40765883046657),
        ],
        rtol=1e-13,
    )
    np.testing.assert_allclose(
        [m.rate_deg_s for m in sc.maneuvers],
        [
            *(1.2810223660969293, 1.1704952089094904, 1.4755438177091782),
            *(1.3022816753184125, 1.4646784524314898, 0.6197587686676327),
        ],
        rtol=1e-13,
    )
    (jump,) = sc.calibration_jumps
    np.testing.assert_allclose(jump.t_s, 2329.628081960269, rtol=1e-13)
    np.testing.assert_allclose(sc.maneuvers[3].start_s, jump.t_s, rtol=1e-13)
    np.testing.assert_allclose(
        jump.scale_factor_ppm, [7.122202416714973, -80.66238337214308, 62.991039811106596]
    )
    np.testing.assert_allclose(
        jump.misalignment_urad,
        [
            *(-141.56219145464092, -188.4092324451737, -137.0393260645945),
            *(177.25619295941914, 266.1940880538721, 172.12356071970896),
        ],
        rtol=1e-13,
    )
    first = draw_events(_config("thermal_snap_random").scenario, trial_streams(0, 0)["events"])
    np.testing.assert_allclose(first.calibration_jumps[0].t_s, 1749.0311629337075, rtol=1e-13)


def test_thermal_drift_random_draws_the_transient_it_drew_before() -> None:
    """The transient comes first in the draw order, so the rotation schedule the family gained
    leaves each (seed, trial)'s transient as it was (values recorded from the earlier code)."""
    sc = _config("thermal_drift_random").scenario
    for (seed, trial), expected in {
        (7000, 3): (1498.964010006111, 2283.4452541943797, 1.8119392003077386e-06),
        (0, 0): (807.6711542127803, 1336.1968342665239, 5.376381311749177e-07),
        (5_000_001, 2): (1773.893134236163, 2431.5986770919276, 7.016278278528596e-07),
    }.items():
        (seg,) = draw_events(sc, trial_streams(seed, trial)["events"]).calibration_walk.segments
        # start and end are uniform draws and their sum (IEEE arithmetic, the same on every
        # CPU); σ is exp of a uniform draw between two np.log values, and numpy's SIMD exp/log
        # differ from libm's in the last bits by CPU: 1e-9 relative, the pin of a computed float
        np.testing.assert_allclose((seg.start_s, seg.end_s), expected[:2], rtol=1e-13)
        np.testing.assert_allclose(seg.sigma_per_sqrt_s, expected[2], rtol=1e-9)


# -- distributions -----------------------------------------------------------------------------


@pytest.mark.parametrize("name", FAMILIES)
def test_rotation_schedule_distribution(name: str) -> None:
    """First sequence: the 6 axis orders equally likely (chi-square), rates and durations
    uniform; back to back from t = 0."""
    scs = [sc for sc, _ in _draws(name)]
    orders = ["".join(m.axis for m in sc.maneuvers[:3]) for sc in scs]
    perms = ["".join(p) for p in itertools.permutations("xyz")]
    counts = [orders.count(p) for p in perms]
    assert sum(counts) == DRAWS
    assert stats.chisquare(counts).pvalue > P_MIN
    _uniform([m.rate_deg_s for sc in scs for m in sc.maneuvers[:3]], *ROTATION["rate_deg_s"])
    _uniform([m.duration_s for sc in scs for m in sc.maneuvers[:3]], *ROTATION["duration_s"])
    for sc in scs[:100]:
        m = sc.maneuvers
        assert m[0].start_s == 0.0
        np.testing.assert_allclose(
            [m[1].start_s, m[2].start_s], [m[0].duration_s, m[0].duration_s + m[1].duration_s]
        )


@pytest.mark.parametrize("name", sorted(JUMPS))
def test_single_jump_distribution(name: str) -> None:
    """One jump: time uniform, every term's magnitude uniform, signs balanced; the second
    rotation sequence starts at the jump."""
    (t_range, ma_range, sf_range) = JUMPS[name]
    scs = [sc for sc, _ in _draws(name)]
    assert all(len(sc.calibration_jumps) == 1 and len(sc.maneuvers) == 6 for sc in scs)
    t, sf, ma = _jump_terms(scs, 0)
    _uniform(t, *t_range)
    _sizes(sf, ma, sf_range, ma_range)
    np.testing.assert_array_equal([sc.maneuvers[3].start_s for sc in scs], t)


def test_double_jump_distribution() -> None:
    """Two jumps uniform on {a ≤ t₁, t₁ + d ≤ t₂ ≤ b}: with L = b − a − d, (t₁ − a)/L ~
    Beta(1, 2), (t₂ − a − d)/L ~ Beta(2, 1), (t₂ − t₁ − d)/L ~ Beta(1, 2) (exact CDFs); each
    jump with its own sizes and signs and its own rotation sequence."""
    (a, b), d = DOUBLE_T, DOUBLE_SEPARATION
    span = b - a - d
    scs = [sc for sc, _ in _draws("double_snap_random")]
    assert all(len(sc.calibration_jumps) == 2 and len(sc.maneuvers) == 9 for sc in scs)
    t1, sf1, ma1 = _jump_terms(scs, 0)
    t2, sf2, ma2 = _jump_terms(scs, 1)
    assert np.all(t2 - t1 >= d - 1e-9) and np.all(t1 >= a) and np.all(t2 <= b + 1e-9)
    for x, dist in (
        (t1, stats.beta(1, 2, loc=a, scale=span)),
        (t2, stats.beta(2, 1, loc=a + d, scale=span)),
        (t2 - t1 - d, stats.beta(1, 2, loc=0.0, scale=span)),
    ):
        assert stats.kstest(x, dist.cdf).pvalue > P_MIN
    for sf, ma in ((sf1, ma1), (sf2, ma2)):
        _sizes(sf, ma, JUMPS["thermal_snap_random"][2], JUMPS["thermal_snap_random"][1])
    # the two jumps' sizes are independent draws, not one draw repeated
    assert abs(np.corrcoef(np.abs(ma1[:, 0]), np.abs(ma2[:, 0]))[0, 1]) < 0.05
    np.testing.assert_array_equal([sc.maneuvers[3].start_s for sc in scs], t1)
    np.testing.assert_array_equal([sc.maneuvers[6].start_s for sc in scs], t2)


def test_drift_distribution() -> None:
    scs = [sc for sc, _ in _draws("thermal_drift_random")]
    segments = [sc.calibration_walk.segments[0] for sc in scs]
    assert all(len(sc.calibration_walk.segments) == 1 and not sc.calibration_jumps for sc in scs)
    _uniform([s.start_s for s in segments], *DRIFT["start_s"])
    _uniform([s.end_s - s.start_s for s in segments], *DRIFT["duration_s"])
    _uniform([np.log(s.sigma_per_sqrt_s) for s in segments], *np.log(DRIFT["sigma"]))
    assert all(sc.calibration_walk.sigma_per_sqrt_s == 1e-9 for sc in scs[:10])


def test_ads_sigma_distribution() -> None:
    scs = [sc for sc, _ in _draws("ads_mismatch_random")]
    _uniform([sc.ads.attitude_sigma_arcsec for sc in scs], *ADS_ARCSEC)
    assert all(not sc.calibration_jumps and not sc.calibration_walk.segments for sc in scs)
    assert all(sc.ads.rate_sigma_degph == 0.02 for sc in scs[:10])


def test_no_change_in_steady_random() -> None:
    for sc, _ in _draws("steady_random")[:200]:
        assert not sc.calibration_jumps and not sc.calibration_walk.segments
        assert sc.ads.attitude_sigma_arcsec == 3.0 and len(sc.maneuvers) == 3


def test_mixture_draws_its_components_uniformly() -> None:
    """Component counts uniform (chi-square); within a component, its own family's events
    (here: the thermal-snap component's jump times, and each component's structure)."""
    draws = _draws("mixed_random")
    family = np.array([k for _, k in draws])
    counts = np.bincount(family, minlength=len(FAMILIES))
    assert counts.sum() == DRAWS and stats.chisquare(counts).pvalue > P_MIN
    jumps = {
        "double_snap_random": 2,
        "steady_random": 0,
        "thermal_drift_random": 0,
        "ads_mismatch_random": 0,
        "rotation_only_random": 0,
    }
    sequences = {"rotation_only_random": 3}  # else 1 + one per jump
    for sc, k in draws:
        assert k is not None and len(sc.calibration_jumps) == jumps.get(FAMILIES[k], 1)
        n_seq = sequences.get(FAMILIES[k], 1 + len(sc.calibration_jumps))
        assert len(sc.maneuvers) == 3 * n_seq
        assert bool(sc.calibration_walk.segments) == (FAMILIES[k] == "thermal_drift_random")
        assert (sc.ads.attitude_sigma_arcsec != 3.0) == (FAMILIES[k] == "ads_mismatch_random")
    snap = [sc for sc, k in draws if FAMILIES[k or 0] == "thermal_snap_random"]
    _uniform(_jump_terms(snap, 0)[0], *JUMPS["thermal_snap_random"][0])


def test_mixture_trial_is_its_component_drawn_after_the_index() -> None:
    """A mixed trial draws the component index, then exactly what the component's scenario
    (:func:`component_scenario`) draws from the rest of the stream."""
    sc = _config("mixed_random").scenario
    for i in range(40):
        drawn, k = draw_trial(sc, np.random.default_rng([SEED, 99, i]))
        rng = np.random.default_rng([SEED, 99, i])
        assert k == int(rng.integers(len(FAMILIES)))
        assert drawn == draw_events(component_scenario(sc, k), rng)


def test_mixture_components_are_the_family_presets() -> None:
    """mixed_random's components are the other presets' ``random_events``, on the same base
    scenario and filter, so that a component's trials are drawn as its family's are."""
    mixed = _config("mixed_random")
    ev = mixed.scenario.random_events
    assert ev is not None and ev.mixture is not None
    assert [c.name for c in ev.mixture] == list(FAMILIES)
    nominal = {"random_events", "maneuvers", "calibration_jumps", "calibration_walk", "ads"}
    for k, component in enumerate(ev.mixture):
        family = _config(component.name)
        own = family.scenario.random_events
        assert own is not None and own.mixture is None
        assert component.events.model_dump() == own.model_dump(exclude={"mixture"})
        assert family.scenario.model_dump(exclude=nominal) == mixed.scenario.model_dump(
            exclude=nominal
        )
        for part in ("calibration_walk", "ads"):  # the base walk and ADS; segments are drawn
            mine, theirs = getattr(mixed.scenario, part), getattr(family.scenario, part)
            assert mine.model_dump(exclude={"segments"}) == theirs.model_dump(exclude={"segments"})
        assert FilterParams.from_config(family).sigma_a == FilterParams.from_config(mixed).sigma_a
        assumed = {"attitude_sigma_arcsec"}  # explicit 3″ in the mixture (and the ADS family)
        assert family.filter.model_dump(exclude=assumed) == mixed.filter.model_dump(exclude=assumed)
        for i in range(5):  # the same stream gives the same trial scenario
            rng_a, rng_b = (np.random.default_rng([SEED, 7, i]) for _ in range(2))
            assert draw_events(family.scenario, rng_a) == draw_events(
                component_scenario(mixed.scenario, k), rng_b
            )


# -- what the simulation makes of the draws ----------------------------------------------------


def test_true_ads_noise_is_the_drawn_sigma() -> None:
    """ads_mismatch_random: each trial's attitude noise Log(C_trueᵀ C_ADS) has the σ it drew
    (RMS over 3 × 3600 samples: 0.7 % standard error, 3 % allowed), the filter assumes 3″."""
    cfg = _config("ads_mismatch_random")
    d = simulate(cfg, SEED, 4)
    assert d.ads_sigma_rad is not None
    drawn = d.ads_sigma_rad / units.ARCSEC
    assert np.all((drawn >= 3.0) & (drawn <= 10.0)) and np.ptp(drawn) > 0.1
    nu = (
        Rotation.from_quat(d.q_true.reshape(-1, 4)).inv()
        * Rotation.from_quat(d.ads_q.reshape(-1, 4))
    ).as_rotvec()
    rms = np.sqrt(np.mean(nu.reshape(d.n_trials, -1) ** 2, axis=1))
    np.testing.assert_allclose(rms, d.ads_sigma_rad, rtol=0.03)
    assert FilterParams.from_config(cfg).sigma_a == 3.0 * units.ARCSEC
    # in the mixture, the other families' trials keep the nominal 3″
    mixed = simulate(_config("mixed_random"), SEED, 10)
    assert mixed.family is not None and mixed.ads_sigma_rad is not None
    others = mixed.family != FAMILIES.index("ads_mismatch_random")
    assert others.any()
    np.testing.assert_array_equal(mixed.ads_sigma_rad[others], 3.0 * units.ARCSEC)


def test_jumps_t_lists_every_jump_and_the_oracle_opens_a_window_at_each() -> None:
    d = simulate(_config("double_snap_random"), SEED, 3)
    assert d.jumps_t is not None and d.jumps_t.shape == (3, 2)
    steps = np.abs(np.diff(d.calib[:, :, 3:9], axis=1)).min(axis=-1) / units.URAD  # (B, N−1)
    for row in range(3):
        t1, t2 = d.jumps_t[row]
        assert t2 - t1 >= 600.0 - 1e-9
        k = np.ceil(d.jumps_t[row] / d.dt - 1e-9).astype(int)  # first epochs after the jumps
        assert np.all(steps[row, k - 1] >= 100.0 - 1e-3)  # every term jumps ≥ 100 µrad
        assert np.sort(np.argsort(steps[row])[-2:]).tolist() == (k - 1).tolist()
    kappa = schedule(d, 1.0, 10.0, 100.0)
    t = d.t[None, :]
    inside = np.zeros_like(kappa, dtype=bool)
    for column in d.jumps_t.T:
        inside |= (t >= column[:, None] - 1e-9) & (t < column[:, None] + 100.0 - 1e-9)
    np.testing.assert_array_equal(kappa, np.where(inside, 10.0, 1.0))
    assert np.all((kappa == 10.0).sum(axis=1) == 200)  # two windows of 100 epochs each


def test_fixed_schedule_jumps_t() -> None:
    d = simulate(load_config("thermal_snap", ["scenario.duration_s=300"]), SEED, 2)
    assert d.jumps_t is not None and d.family is None and d.ads_sigma_rad is None
    np.testing.assert_array_equal(d.jumps_t, [[1800.0], [1800.0]])
    none = simulate(load_config("paper", ["scenario.duration_s=100"]), SEED, 1)
    assert none.jumps_t is not None and none.jumps_t.shape == (1, 1)
    assert np.isnan(none.jumps_t).all()


# -- the schema refuses what cannot be drawn ---------------------------------------------------


@pytest.mark.parametrize(
    ("preset", "sets", "words"),
    [
        (  # 3 jumps 1000 s apart need 2000 s; [900, 2700] spans 1800
            "double_snap_random",
            [
                "scenario.random_events.jump.count=3",
                "scenario.random_events.jump.min_separation_s=1000",
            ],
            ["scenario.random_events.jump", "min_separation_s", "count"],
        ),
        (
            "double_snap_random",
            ["scenario.random_events.jump.min_separation_s=1800"],  # exactly the span
            ["min_separation_s"],
        ),
        ("thermal_snap_random", ["scenario.random_events.jump.count=5"], ["jump.count"]),
        (
            "thermal_snap_random",
            ["scenario.random_events.jump.min_separation_s=-1"],
            ["min_separation_s"],
        ),
        (
            "ads_mismatch_random",
            ["scenario.random_events.ads_attitude_sigma_arcsec={low: 0, high: 5}"],
            ["ads_attitude_sigma_arcsec", "positive"],
        ),
        (
            "mixed_random",
            [
                "scenario.random_events.drift={start_s: {low: 0, high: 1}, "
                "duration_s: {low: 1, high: 2}, sigma_per_sqrt_s: {low: 1e-7, high: 1e-6}}"
            ],
            ["mixture", "drift"],
        ),
        (
            "mixed_random",
            ["scenario.random_events.mixture=[{name: a, events: {mixture: []}}]"],
            ["mixture.0.events.mixture", "unknown key"],
        ),
        (
            "mixed_random",
            ["scenario.random_events.mixture=[{name: a, events: {}}, {name: a, events: {}}]"],
            ["unique"],
        ),
        ("mixed_random", ["scenario.random_events.mixture=[]"], ["mixture"]),
    ],
)
def test_schema_refuses_events_that_cannot_be_drawn(
    preset: str, sets: list[str], words: list[str]
) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(preset, sets)
    for word in words:
        assert word in str(err.value), str(err.value)


def test_one_jump_with_a_separation_is_fine() -> None:
    cfg = load_config("thermal_snap_random", ["scenario.random_events.jump.min_separation_s=1e6"])
    sc = draw_events(cfg.scenario, trial_streams(SEED, 0)["events"])
    assert len(sc.calibration_jumps) == 1
