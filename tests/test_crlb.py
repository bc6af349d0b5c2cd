"""The Cramér–Rao bound: physics of the problem, the SPEC's information-form recursion, and
agreement with the filter's covariance when the filter's model is the truth."""

from __future__ import annotations

import numpy as np
import pytest

from qkf.core import units
from qkf.transfer_alignment.crlb import crlb
from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.model import calibration_matrix, discretize, measurement_model
from qkf.transfer_alignment.params import TruthParams
from qkf.transfer_alignment.scenario import simulate, true_rates
from tests.conftest import cfg_with


@pytest.fixture(scope="module")
def bounds() -> dict[str, np.ndarray]:
    cfg = cfg_with()
    return {
        "rate": crlb(cfg, use_rate=True).bound,
        "att": crlb(cfg, use_rate=False).bound,
    }


def test_rate_matching_never_loosens_the_bound(bounds) -> None:  # type: ignore[no-untyped-def]
    assert np.all(bounds["rate"] <= bounds["att"] * (1 + 1e-9))
    # it helps: attitude throughout; bias and calibration as soon as they are separable
    # (t = 300 s, when the x row has seen four different rate vectors) and to the end
    assert np.all(bounds["rate"][1:, 0:3] < 0.8 * bounds["att"][1:, 0:3])
    assert np.all(bounds["rate"][305, 3:] < 0.1 * bounds["att"][305, 3:])
    assert np.all(bounds["rate"][-1] < 0.9 * bounds["att"][-1])


def test_bias_and_scale_factor_inseparable_at_constant_rate(bounds) -> None:  # type: ignore[no-untyped-def]
    prior_b = 2.0 * units.DEG_PER_H
    for name in ("rate", "att"):
        bx = bounds[name][:, 3]
        # during the x rotation (0-100 s) the x bias stays near its prior …
        assert bx[99] > 0.7 * prior_b
        # … and once the rates have changed it falls by orders of magnitude
        assert bx[400] < 1e-2 * bx[99]
        assert bx[-1] < 1e-3 * prior_b


def test_information_form_of_the_spec_agrees_for_attitude_matching() -> None:
    """SPEC §4's recursion, written literally in information form (no correlated noise)."""
    cfg = cfg_with("scenario.duration_s=600", "filter.matching=attitude")
    ours = crlb(cfg).bound
    tp = TruthParams.from_config(cfg)
    fp = FilterParams.from_config(cfg)
    w = true_rates(cfg.scenario)
    a = np.linalg.inv(np.eye(3) + calibration_matrix(tp.p0))
    a = np.broadcast_to(a, (w.shape[0], 3, 3))
    phi, qd = discretize(w, a, tp.dt, tp.sigma_v, tp.sigma_u, 1e-20)
    h, r = measurement_model(w, a, tp.dt, tp.sigma_a, tp.sigma_r, tp.sigma_v, False)
    d = fp.p0_sigma  # solve in scaled units: J spans 1e10…1e18 otherwise
    s = np.diag(d)
    si = np.diag(1 / d)
    j = np.eye(15)  # J_0 = P_0⁻¹ in scaled units
    for k in range(w.shape[0]):
        hk = h[k] @ s
        j = j + hk.T @ np.linalg.inv(r[k]) @ hk
        cov = np.linalg.inv(j)
        np.testing.assert_allclose(np.sqrt(np.diag(cov)) * d, ours[k], rtol=1e-7)
        phik = si @ phi[k] @ s
        j = np.linalg.inv(si @ qd[k] @ si + phik @ cov @ phik.T)


@pytest.mark.parametrize("matching", ["attitude", "attitude_rate"])
def test_bound_equals_filter_covariance_when_the_model_is_the_truth(matching: str) -> None:
    cfg = cfg_with(
        "scenario.randomize_truth=true", "filter.qp0=1e-20", f"filter.matching={matching}"
    )
    data = simulate(cfg, 5, 4)
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 4)
    kf.initialize(data.ads_q[:, 0])
    rec = kf.step_data(data, 0, data.n_epochs)
    sigma = np.sqrt(rec.var)
    bound = crlb(cfg).bound
    # The filter linearises at its estimate, the bound at the truth; after convergence the
    # two recursions coincide closely.
    late = data.t >= 400
    ratio = sigma[:, late] / bound[late]
    assert np.all(np.abs(ratio - 1) < 0.02), np.abs(ratio - 1).max()
