"""The least-squares core (qkf.core.banded, qkf.core.least_squares, qkf.core.vce), each piece
against a dense reference on small problems: banded-bordered solve and selected inverse,
redundancy numbers, variance components, Huber weights, and the iteration with its stopping
rule."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.integrate import quad
from scipy.stats import norm

from qkf.core.banded import BandedBorderedCholesky, NotPositiveDefiniteError, takahashi_band
from qkf.core.least_squares import (
    IterationSettings,
    Linearization,
    ObservationGroup,
    design_bandwidth,
    iterate,
    leverages,
    normal_equations,
    whiten,
)
from qkf.core.vce import RobustSettings, estimate_group, full_weight_residual, truncation_factor


def banded_design(rng: np.random.Generator, m: int, n_band: int, width: int, g: int) -> np.ndarray:
    """Rows touching ``width`` consecutive band columns and (half of them) the border."""
    a = np.zeros((m, n_band + g))
    for i in range(m):
        j = rng.integers(0, n_band - width + 1) if n_band else 0
        a[i, j : j + width] = rng.normal(size=min(width, n_band))
        if g and rng.random() < 0.5:
            a[i, n_band:] = rng.normal(size=g)
    return a


@pytest.mark.parametrize(("n_band", "width", "g"), [(40, 4, 3), (30, 1, 2), (25, 3, 0), (0, 0, 5)])
def test_banded_bordered_factor_matches_dense(n_band: int, width: int, g: int) -> None:
    rng = np.random.default_rng(n_band + 10 * g)
    a = banded_design(rng, 6 * (n_band + g), n_band, width, g)
    n = a.T @ a + 0.05 * np.eye(n_band + g)
    f = BandedBorderedCholesky(sp.csr_matrix(n), n_band)
    assert f.bandwidth == max(width - 1, 0)
    ref = np.linalg.inv(n)
    rhs = rng.normal(size=(n_band + g, 2))
    np.testing.assert_allclose(f.solve(rhs), np.linalg.solve(n, rhs), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(f.inverse_diagonal(), np.diag(ref), rtol=1e-9)
    np.testing.assert_allclose(f.border_covariance(), ref[n_band:, n_band:], rtol=1e-9)
    np.testing.assert_allclose(f.band_border_inverse(), ref[:n_band, n_band:], atol=1e-12)
    sel = f.selected_inverse().toarray()
    on = sel != 0.0
    assert on.sum() >= np.count_nonzero(n) - 2  # the whole pattern of N (up to cancellation)
    np.testing.assert_allclose(sel[on], ref[on], rtol=1e-8, atol=1e-13)


def test_takahashi_band_wider_than_the_factor() -> None:
    """The recursion on a zero-padded band gives the inverse on any wider band."""
    rng = np.random.default_rng(3)
    m = rng.normal(size=(30, 30)) * (np.abs(np.subtract.outer(range(30), range(30))) <= 2)
    n = m @ m.T + 30 * np.eye(30)  # bandwidth 4
    f = BandedBorderedCholesky(n, 30)
    ref = np.linalg.inv(n)
    for q in (4, 7):
        band = f.inverse_band(q)
        for k in range(q + 1):
            np.testing.assert_allclose(band[k, : 30 - k], np.diag(ref, -k), rtol=1e-9, atol=1e-14)
    # the compiled recursion alone, on a hand-made factor
    low = np.array([[2.0, 3.0, 1.0], [0.5, 0.25, 0.0]])
    lmat = np.diag(low[0]) + np.diag(low[1, :2], -1)
    sig = takahashi_band(low, 2)
    ref2 = np.linalg.inv(lmat @ lmat.T)
    np.testing.assert_allclose(sig[0], np.diag(ref2))
    np.testing.assert_allclose(sig[1, :2], np.diag(ref2, -1))
    np.testing.assert_allclose(sig[2, :1], np.diag(ref2, -2))


def test_leverages_and_redundancy_against_dense() -> None:
    rng = np.random.default_rng(7)
    n_band, g = 50, 4
    a = banded_design(rng, 400, n_band, 3, g)
    w = rng.uniform(0.5, 2.0, 400)
    aw = a * w[:, None]
    n = aw.T @ aw
    f = BandedBorderedCholesky(sp.csr_matrix(n), n_band)
    h_ref = np.einsum("ij,jk,ik->i", aw, np.linalg.inv(n), aw)
    h = leverages(sp.csr_matrix(aw), f)
    np.testing.assert_allclose(h, h_ref, rtol=1e-9, atol=1e-12)
    assert np.sum(1.0 - h) == pytest.approx(400 - (n_band + g), rel=1e-9)  # Σ r = n − u
    # a row spanning more than the band held must be refused, not silently wrong
    wide = sp.csr_matrix(([1.0, 1.0], ([0, 0], [0, 10])), shape=(1, n_band + g))
    with pytest.raises(ValueError, match="half width"):
        leverages(wide, f, 2)


def test_normal_equations_and_bandwidth_by_hand() -> None:
    a = sp.csr_matrix(np.array([[1.0, 2.0, 0.0, 0.0, 1.0], [0.0, 0.0, 3.0, -1.0, 0.0]]))
    assert design_bandwidth(a, 4) == 1  # border column 4 does not count
    assert design_bandwidth(a, 2) == 1
    assert design_bandwidth(sp.csr_matrix((3, 5)), 4) == 0
    g = ObservationGroup("g", a, np.array([1.0, 2.0]), np.array([0.5, 2.0]))
    ne = normal_equations([whiten(g, g.sigma)], 5, prior_normal=np.full(5, 0.1))
    ad = a.toarray() / g.sigma[:, None]
    np.testing.assert_allclose(ne.matrix.toarray(), ad.T @ ad + 0.1 * np.eye(5))
    np.testing.assert_allclose(ne.rhs, ad.T @ (g.residual / g.sigma))
    assert ne.lpl == pytest.approx(4.0 + 1.0) and ne.n_obs == 2


def test_singular_normal_matrix_is_refused() -> None:
    a = np.zeros((4, 3))
    a[:, 0] = 1.0
    a[:, 2] = [1.0, 2.0, 3.0, 4.0]  # parameter 1 is in no row
    with pytest.raises(NotPositiveDefiniteError):
        BandedBorderedCholesky(a.T @ a, 2)
    with pytest.raises(NotPositiveDefiniteError):
        BandedBorderedCholesky(a.T @ a, 0)


def test_truncation_factor() -> None:
    """κ_m: mean square of a kept component, by quadrature (m = 1) and Monte Carlo (m = 3)."""
    h = 2.5
    kept = quad(lambda x: x * x * norm.pdf(x), -h, h)[0] / (2.0 * norm.cdf(h) - 1.0)
    assert truncation_factor(1, h) == pytest.approx(kept, rel=1e-10)
    x = np.random.default_rng(0).standard_normal((400_000, 3))
    keep = np.mean(x**2, axis=1) <= h * h
    mc = np.mean(x[keep] ** 2)
    assert truncation_factor(3, h) == pytest.approx(mc, abs=4.0 * np.sqrt(2.0 / x[keep].size))
    assert truncation_factor(3, h) < 1.0
    assert truncation_factor(3, None) == 1.0


def test_full_weight_residual_is_the_refit_at_full_weight() -> None:
    """Downweight one row, then compare the identity with an actual dense refit."""
    rng = np.random.default_rng(11)
    a = rng.normal(size=(30, 4))
    y = a @ rng.normal(size=4) + rng.normal(size=30)

    def fit(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        aw = a * np.sqrt(weights)[:, None]
        x = np.linalg.lstsq(aw, y * np.sqrt(weights), rcond=None)[0]
        h = np.einsum("ij,jk,ik->i", aw, np.linalg.inv(aw.T @ aw), aw)
        return y - a @ x, 1.0 - h

    factor = np.ones(30)
    factor[5] = 3.0
    e_f, r_f = fit(1.0 / factor**2)
    e_1, r_1 = fit(np.ones(30))
    e, r = full_weight_residual(e_f, r_f, factor)
    assert e[5] == pytest.approx(e_1[5], rel=1e-10) and r[5] == pytest.approx(r_1[5], rel=1e-10)
    assert np.array_equal(e[:5], e_f[:5])  # full-weight rows unchanged


def two_group_problem(
    seed: int, n: int, sigmas: tuple[float, float], outliers: int = 0
) -> tuple[list[ObservationGroup], np.ndarray, np.ndarray]:
    """A straight line observed by two sensors of different noise; optional gross errors."""
    rng = np.random.default_rng(seed)
    t = np.linspace(-1.0, 1.0, n)
    a = sp.csr_matrix(np.column_stack([np.ones(n), t]))
    truth = np.array([0.3, -1.2])
    groups, bad = [], np.zeros(0, dtype=int)
    for k, s in enumerate(sigmas):
        y = a @ truth + s * rng.standard_normal(n)
        if k == 0 and outliers:
            bad = rng.choice(n, outliers, replace=False)
            y[bad] += 30.0 * s * rng.choice([-1.0, 1.0], outliers)
        groups.append(ObservationGroup(f"g{k}", a, y, np.ones(n)))
    return groups, truth, bad


def test_variance_components_recover_the_group_sigmas() -> None:
    """Two groups, prior sigma 1 for both; σ̂ within 4 sd of the truth, sd = σ/√(2 Σ r)."""
    sigmas = (0.2, 3.0)
    groups, truth, _ = two_group_problem(1, 4000, sigmas)
    x = np.zeros(2)

    def lin() -> Linearization:
        return Linearization(
            [
                ObservationGroup(g.name, g.design, g.residual - g.design @ x, g.sigma)
                for g in groups
            ],
            2,
        )

    def update(dx: np.ndarray) -> None:
        x[:] += dx

    res = iterate(lin, update, IterationSettings(max_iterations=30, tolerance=1e-10))
    assert res.converged
    for k, s in enumerate(sigmas):
        est = res.component_sigma[f"g{k}"][0]
        sd = s / np.sqrt(2.0 * res.redundancy[f"g{k}"].sum())
        assert abs(est - s) < 4.0 * sd
    assert abs(x - truth).max() < 0.05


def test_one_vce_step_against_dense_formula() -> None:
    """σ̂² = Σ (e/σ)² / Σ r for one group, with e and r from a dense solve."""
    groups, _, _ = two_group_problem(2, 300, (0.5, 2.0))
    sig = [0.7, 1.5]
    aw = np.vstack([g.design.toarray() / s for g, s in zip(groups, sig, strict=True)])
    lw = np.concatenate([g.residual / s for g, s in zip(groups, sig, strict=True)])
    x = np.linalg.lstsq(aw, lw, rcond=None)[0]
    r = 1.0 - np.einsum("ij,jk,ik->i", aw, np.linalg.inv(aw.T @ aw), aw)
    g0 = groups[0]
    e0 = g0.residual - g0.design @ x
    est = estimate_group(
        e0,
        g0.sigma,
        g0.component,
        g0.epochs,
        r[:300],
        np.array([sig[0]]),
        np.ones(300),
        True,
        RobustSettings(huber=None),
    )
    expected = sig[0] * np.sqrt(np.sum((e0 / sig[0]) ** 2) / np.sum(r[:300]))
    assert est.component_sigma[0] == pytest.approx(expected, rel=1e-12)
    assert np.all(est.epoch_sigma == 1.0)


def test_huber_downweights_the_gross_errors_only() -> None:
    groups, truth, bad = two_group_problem(3, 1000, (0.1, 0.1), outliers=15)
    x = np.zeros(2)

    def lin() -> Linearization:
        return Linearization(
            [
                ObservationGroup(g.name, g.design, g.residual - g.design @ x, g.sigma)
                for g in groups
            ],
            2,
        )

    def update(dx: np.ndarray) -> None:
        x[:] += dx

    res = iterate(lin, update, IterationSettings(max_iterations=30))
    f = res.epoch_sigma["g0"]
    assert np.all(f[bad] >= 4.0)  # 30σ errors: s ≈ 30 → (30/2.5)^1.5 ≈ 42
    good = np.setdiff1d(np.arange(1000), bad)
    assert np.mean(f[good] > 1.0) < 0.03  # Gaussian epochs: P(|z| > 2.5) = 1.2 %
    assert res.component_sigma["g0"][0] == pytest.approx(0.1, rel=0.1)
    assert abs(x - truth).max() < 0.02
    # without Huber the gross errors inflate the group's sigma: the check above can fail
    x[:] = 0.0
    plain = iterate(lin, update, IterationSettings(robust=RobustSettings(huber=None)))
    assert plain.component_sigma["g0"][0] > 2.0 * res.component_sigma["g0"][0]


def test_stopping_rule_and_iteration_count() -> None:
    groups, _, _ = two_group_problem(4, 200, (1.0, 1.0))
    x = np.zeros(2)
    calls = []

    def lin() -> Linearization:
        calls.append(1)
        return Linearization(
            [
                ObservationGroup(g.name, g.design, g.residual - g.design @ x, g.sigma)
                for g in groups
            ],
            2,
        )

    def update(dx: np.ndarray) -> None:
        x[:] += dx

    fixed = IterationSettings(variance_components=False, robust=RobustSettings(huber=None))
    res = iterate(lin, update, fixed)
    # linear problem, fixed weights: solved in the first iteration, σ₀ repeats in the second
    assert res.converged and res.iterations == 2 and len(calls) == 2
    assert res.sigma0[0] == pytest.approx(res.sigma0[1], abs=1e-12)
    x[:] = 0.0
    never = IterationSettings(max_iterations=4, tolerance=0.0)
    res = iterate(lin, update, never)
    assert not res.converged and res.iterations == 4


def test_gauss_newton_on_a_nonlinear_dense_problem() -> None:
    """No band (n_band = 0): y = a·exp(b t) fitted from a bad start, as scipy finds it."""
    from scipy.optimize import least_squares

    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 2.0, 60)
    y = 1.5 * np.exp(-0.8 * t) + 0.01 * rng.standard_normal(60)
    p = np.array([1.0, 0.0])

    def lin() -> Linearization:
        f = p[0] * np.exp(p[1] * t)
        jac = np.column_stack([np.exp(p[1] * t), p[0] * t * np.exp(p[1] * t)])
        return Linearization(
            [ObservationGroup("y", sp.csr_matrix(jac), y - f, np.full(60, 0.01))], 2
        )

    def update(dx: np.ndarray) -> None:
        p[:] += dx

    plain = IterationSettings(max_iterations=30, tolerance=1e-12, robust=RobustSettings(None))
    res = iterate(lin, update, plain)
    ref = least_squares(lambda q: q[0] * np.exp(q[1] * t) - y, [1.0, 0.0], xtol=1e-14).x
    assert res.converged
    np.testing.assert_allclose(p, ref, rtol=1e-6)
