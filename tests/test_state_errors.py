"""``state_errors`` (compiled) against the error convention written out in numpy: δθ = Log(Ĉᵀ C),
Δb = b − b̂, Δp = p − p̂ (docs/models.md)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.transfer_alignment.metrics import state_errors


def _draw(rng: np.random.Generator, b: int, n: int) -> tuple[np.ndarray, ...]:
    q_true = Rotation.random(b * n, random_state=rng).as_quat().reshape(b, n, 4)
    small = Rotation.from_rotvec(rng.normal(0.0, 1e-3, (b * n, 3)))
    q_hat = (Rotation.from_quat(q_true.reshape(-1, 4)) * small).as_quat().reshape(b, n, 4)
    q_hat *= rng.uniform(0.5, 2.0, (b, n, 1))  # any length: both sides are normalised
    est = np.concatenate([q_hat, rng.normal(size=(b, n, 12))], axis=2)
    return est, q_true, rng.normal(size=(b, n, 3)), rng.normal(size=(b, n, 9))


def _numpy_errors(est: np.ndarray, q_true: np.ndarray, bias: np.ndarray, calib: np.ndarray):  # type: ignore[no-untyped-def]
    b, n = est.shape[:2]
    q_t = np.broadcast_to(q_true, (b, n, 4)).reshape(-1, 4)
    att = Rotation.from_quat(est[..., :4].reshape(-1, 4)).inv() * Rotation.from_quat(q_t)
    return np.concatenate(
        [att.as_rotvec().reshape(b, n, 3), bias - est[..., 4:7], calib - est[..., 7:16]], axis=2
    )


def test_state_errors_against_numpy() -> None:
    rng = np.random.default_rng(11)
    est, q_true, bias, calib = _draw(rng, 3, 7)
    err = state_errors(est, q_true, bias, calib)
    np.testing.assert_allclose(err, _numpy_errors(est, q_true, bias, calib), rtol=1e-9, atol=1e-15)
    # the additive states are plain differences, bit for bit
    np.testing.assert_array_equal(err[..., 3:6], bias - est[..., 4:7])
    np.testing.assert_array_equal(err[..., 6:], calib - est[..., 7:16])


def test_state_errors_shared_truth_strided_views_and_nan() -> None:
    rng = np.random.default_rng(12)
    est, q_true, bias, calib = _draw(rng, 2, 9)
    shared = q_true[0]  # (n, 4): one truth for every trial
    ref = _numpy_errors(est[:, 1:8], shared[1:8], bias[:, 1:8], calib[:, 1:8])
    est[1, 4, 2] = np.nan  # a diverged estimate: attitude error NaN, the rest as computed
    err = state_errors(est[:, 1:8], shared[1:8], bias[:, 1:8], calib[:, 1:8])
    assert np.isnan(err[1, 3, :3]).all() and np.isfinite(err[1, 3, 3:]).all()
    ok = np.ones(err.shape, dtype=bool)
    ok[1, 3, :3] = False
    np.testing.assert_allclose(err[ok], ref[ok], rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize(
    ("which", "shape"), [("q_true", (2, 5, 3)), ("bias", (2, 4, 3)), ("calib", (1, 5, 9))]
)
def test_state_errors_rejects_mismatched_shapes(which: str, shape: tuple[int, ...]) -> None:
    arrays = {
        "est": np.zeros((2, 5, 16)),
        "q_true": np.zeros((2, 5, 4)),
        "bias": np.zeros((2, 5, 3)),
        "calib": np.zeros((2, 5, 9)),
    }
    arrays[which] = np.zeros(shape)
    with pytest.raises(ValueError, match=which):
        state_errors(arrays["est"], arrays["q_true"], arrays["bias"], arrays["calib"])
