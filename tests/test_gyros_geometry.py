"""Redundant-gyro geometry: parity identities, the paper's axes, three-cross signatures for any
body rate (checked against dense pseudo-inverses), the separability report and config checks."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest

from qkf.core.config import ConfigError
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.geometry import build_unit, parity_matrix
from qkf.redundant_gyros.threecross import feature, feature_table

TOL = 1e-10


def _random_axes(rng: np.random.Generator, n: int) -> np.ndarray:
    w = rng.standard_normal((n, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True)


def _check_parity(w: np.ndarray) -> None:
    v = parity_matrix(w)
    n = w.shape[0]
    assert v.shape == (n - 3, n)
    assert np.abs(v @ w).max() < TOL
    assert np.abs(v @ v.T - np.eye(n - 3)).max() < TOL
    proj = w @ np.linalg.solve(w.T @ w, w.T)  # W (WᵀW)⁻¹ Wᵀ, formed independently of the QR
    assert np.abs(proj + v.T @ v - np.eye(n)).max() < TOL


def test_parity_identities_for_the_paper_unit() -> None:
    unit = build_unit(load_config("five_gyros"))
    _check_parity(unit.w)
    _check_parity(unit.g)
    whitened = unit.g / unit.comp_noise[:, None]
    _check_parity(whitened)
    assert np.abs(unit.v_parity @ whitened).max() < TOL


@pytest.mark.parametrize("n", [4, 5, 6, 8, 12])
def test_parity_identities_for_random_units(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(5):
        _check_parity(_random_axes(rng, n))


def test_paper_axes() -> None:
    unit = build_unit(load_config("five_gyros"))
    a1, b1, a2, b2 = np.radians([55.0, 45.0, 55.0, 75.0])
    s = np.array([np.sin(a1) * np.sin(b1), np.cos(a1), np.sin(a1) * np.cos(b1)])
    t = np.array([np.sin(a2) * np.sin(b2), np.cos(a2), np.sin(a2) * np.cos(b2)])
    np.testing.assert_allclose(unit.w, np.vstack([np.eye(3), s, t]), atol=1e-15)
    us = np.array([-np.cos(a1) * np.sin(b1), np.sin(a1), -np.cos(a1) * np.cos(b1)])
    ut = np.array([-np.cos(a2) * np.sin(b2), np.sin(a2), -np.cos(a2) * np.cos(b2)])
    np.testing.assert_allclose(unit.u, np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0], us, ut]))
    for w, u, v in zip(unit.w, unit.u, unit.v, strict=True):  # right-handed orthonormal triads
        m = np.vstack([u, v, w])
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(np.cross(w, u), v, atol=1e-15)
    np.testing.assert_allclose(unit.nominal[:, :2], [[0.01, 0.002]] * 5)


def _signature_by_pinv(w: np.ndarray, models: tuple[tuple[int, ...], ...], i: int) -> float:
    cols = []
    for m in models:
        c = np.zeros(3)
        if i in m:
            c = np.linalg.pinv(w[list(m)])[:, list(m).index(i)]
        cols.append(c)
    return float(np.linalg.norm(cols[0] - cols[1]) / np.linalg.norm(cols[0] - cols[2]))


def test_signatures_match_a_dense_pseudo_inverse() -> None:
    unit = build_unit(load_config("five_gyros"))
    for i in range(unit.n):
        assert unit.signature[i] == pytest.approx(_signature_by_pinv(unit.g, unit.models, i))
    # the five signatures are distinct: the paper's design separates every gyro
    assert len({round(float(s), 6) for s in unit.signature}) == 5


@pytest.mark.parametrize("kind", ["bias", "scale", "misalignment"])
def test_a_pure_single_fault_gives_the_signature_for_any_body_rate(kind: str) -> None:
    """Noise-free readings with the nominal errors (compensated) and one faulty gyro: the
    feature equals that gyro's signature at every one of many random body rates."""
    unit = build_unit(load_config("five_gyros"))
    rng = np.random.default_rng(7)
    rates = rng.normal(0.0, 5.0, (500, 3))
    for i in range(unit.n):
        coeffs = np.broadcast_to(unit.nominal, (rates.shape[0], unit.n, 4)).copy()
        if kind == "bias":
            coeffs[:, i, 0] += rng.uniform(-1.0, 1.0, rates.shape[0])
        elif kind == "scale":
            coeffs[:, i, 1] += 0.05
        else:
            coeffs[:, i, 2] += np.radians(3.0)
            coeffs[:, i, 3] -= np.radians(2.0)
        y = unit.compensate(unit.readings(coeffs, rates))
        np.testing.assert_allclose(feature(unit, y), unit.signature[i], rtol=1e-9)


def test_feature_table_nominal_and_with_errors() -> None:
    cfg = load_config("five_gyros")
    unit = build_unit(cfg)
    rows = feature_table(unit, 0.1, np.array([1.0, 1.0, 1.0]))
    assert [r.gyro for r in rows] == list(unit.ids)
    np.testing.assert_allclose([r.nominal for r in rows], unit.signature, rtol=1e-12)
    with_errors = np.array([r.with_errors for r in rows])
    assert np.all(np.abs(with_errors - unit.signature) > 1e-3)  # the errors move every value
    # a common λ cancels from every model's rate, so only the biases move the values: the same
    # numbers at any body rate
    other = feature_table(unit, 0.1, np.array([-3.0, 0.5, 7.0]))
    np.testing.assert_allclose([r.with_errors for r in other], with_errors, rtol=1e-12)
    # without nominal errors the two columns agree
    clean = build_unit(
        load_config("five_gyros", ["unit.nominal.bias_deg_s=0", "unit.nominal.scale=0"])
    )
    rows0 = feature_table(clean, 0.1, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose([r.with_errors for r in rows0], [r.nominal for r in rows0])


def test_separability_of_the_paper_unit() -> None:
    unit = build_unit(load_config("five_gyros"))
    sep = unit.separability()
    v = unit.v_parity
    cos = {
        (unit.ids[i], unit.ids[j]): abs(v[:, i] @ v[:, j])
        / (np.linalg.norm(v[:, i]) * np.linalg.norm(v[:, j]))
        for i, j in combinations(range(unit.n), 2)
    }
    expected = {pair for pair, c in cos.items() if c > 0.9}
    assert {(a, b) for a, b, _ in sep.glt_weak} == expected == {("X", "Y"), ("Z", "S")}
    for a, b, angle in sep.glt_weak:
        assert angle == pytest.approx(np.degrees(np.arccos(cos[(a, b)])))
    assert not sep.glt_inseparable and not sep.undetectable
    assert not sep.threecross_close and not sep.threecross_undefined
    assert not sep.threecross_unrecoverable


def _unit_with(gyros: str, models: str) -> list[str]:
    return [f"unit.gyros={gyros}", f"fdi.threecross.models={models}"]


def test_four_gyros_detect_but_cannot_isolate() -> None:
    gyros = (
        "[{id: X, w: [1,0,0], u: [0,1,0]}, {id: Y, w: [0,1,0], u: [0,0,1]}, "
        "{id: Z, w: [0,0,1], u: [1,0,0]}, {id: S, alpha_deg: 55, beta_deg: 45}]"
    )
    cfg = load_config(None, _unit_with(gyros, "[[X,Y,Z],[X,Y,S],[Y,Z,S]]"))
    sep = build_unit(cfg).separability()
    assert len(sep.glt_inseparable) == 6  # one parity equation: every pair collinear
    assert any("cannot be told apart" in line for line in sep.lines())


def test_a_duplicated_axis_leaves_the_other_three_inseparable() -> None:
    """X and X2 share an axis. By hand: the left null space is spanned by (1, −1, 0, 0, 0)/√2
    and a vector ⟂ to it, (s₁/2, s₁/2, s₂, s₃, −1) up to scale (rows X, X2, Y, Z, S), so the
    parity columns of Y, Z and S all lie along the second one (collinear: a fault of one of
    them looks like a fault of another), while X and X2 differ in the first."""
    gyros = (
        "[{id: X, w: [1,0,0], u: [0,1,0]}, {id: Y, w: [0,1,0], u: [0,0,1]}, "
        "{id: Z, w: [0,0,1], u: [1,0,0]}, {id: S, alpha_deg: 55, beta_deg: 45}, "
        "{id: X2, w: [1,0,0], u: [0,0,1]}]"
    )
    cfg = load_config(None, _unit_with(gyros, "[[X,Y,Z],[X2,S,Y],[Y,Z,S,X]]"))
    sep = build_unit(cfg).separability()
    assert set(sep.glt_inseparable) == {("Y", "Z"), ("Y", "S"), ("Z", "S")}


@pytest.mark.parametrize(
    ("sets", "message"),
    [
        (["unit.gyros.0.u=[1,0,0]"], "unit.gyros.0: u is not perpendicular to w"),
        (["fdi.threecross.models.0=[X,Y,X]"], "fdi.threecross: Value error, models.0: a gyro"),
        (
            ["scenario.faults=[{gyro: Q, t_s: 1, kind: bias_step, size: 1}]"],
            "scenario.faults.0.gyro: unknown gyro 'Q'",
        ),
        (
            ["scenario.faults=[{gyro: X, t_s: 1, kind: misalignment_step, size: 1}]"],
            "scenario.faults.0: Value error, size: misalignment_step takes",
        ),
        (
            ["unit.gyros.3.alpha_deg=90", "unit.gyros.3.beta_deg=90"],  # S along X
            "fdi.threecross.models.1: the axes of XST do not span three dimensions",
        ),
    ],
)
def test_bad_geometry_and_faults_are_refused_by_name(sets: list[str], message: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_config("five_gyros", sets)
    text = str(err.value)
    assert "five_gyros.yaml (with --set)" in text
    assert message in text


def test_a_degenerate_model_is_named() -> None:
    gyros = (
        "[{id: X, w: [1,0,0], u: [0,1,0]}, {id: Y, w: [0,1,0], u: [0,0,1]}, "
        "{id: Z, w: [0,0,1], u: [1,0,0]}, {id: S, w: [1,1,0], u: [0,0,1]}, "
        "{id: T, alpha_deg: 55, beta_deg: 75}]"
    )
    with pytest.raises(ConfigError, match=r"fdi\.threecross\.models\.1: the axes of XYS"):
        load_config(None, _unit_with(gyros, "[[X,Y,Z],[X,Y,S],[Y,Z,S,T]]"))
