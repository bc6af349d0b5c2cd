"""The compiled Kalman primitives against filterpy's KalmanFilter on a linear time-invariant toy."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from qkf.core import kalman
from qkf.core.jit import SERIAL_BELOW


def _toy(seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    dt = 0.1
    # constant-velocity in 2-D plus a slowly decaying bias state: n = 5, m = 2
    phi = np.eye(5)
    phi[0, 2] = phi[1, 3] = dt
    phi[4, 4] = 0.99
    q = np.diag([1e-4, 1e-4, 1e-2, 1e-2, 1e-3])
    h = np.array([[1.0, 0, 0, 0, 1.0], [0, 1.0, 0, 0, 0]])
    r = np.array([[0.5, 0.1], [0.1, 0.3]])
    x0 = rng.normal(size=5)
    p0 = np.diag(rng.uniform(0.5, 2.0, 5))
    z = rng.normal(size=(200, 2)) * 3.0
    return phi, q, h, r, x0, p0, z


# the same problem several times (the batch axis must not mix members): a small batch runs the
# serial loop, one of SERIAL_BELOW members the parallel one
@pytest.mark.parametrize(("seed", "batch"), [(0, 3), (1, SERIAL_BELOW)])
def test_matches_filterpy_over_200_steps(seed: int, batch: int) -> None:
    phi, q, h, r, x0, p0, z = _toy(seed)
    ref = KalmanFilter(dim_x=5, dim_z=2)
    ref.x, ref.P, ref.F, ref.Q, ref.H, ref.R = x0.copy(), p0.copy(), phi, q, h, r
    x = np.ascontiguousarray(np.broadcast_to(x0, (batch, 5)))
    p = np.ascontiguousarray(np.broadcast_to(p0, (batch, 5, 5)))
    for k in range(200):
        ref.predict()
        kalman.predict(x, p, phi, q)
        ref.update(z[k])
        stats = kalman.update(x, p, np.broadcast_to(z[k], (batch, 2)), h, r)
        assert stats["ok"].all()
        for b in range(batch):
            np.testing.assert_allclose(x[b], ref.x, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(p[b], ref.P, rtol=1e-9, atol=1e-12)
        nis = float(ref.y @ np.linalg.solve(ref.S, ref.y))
        np.testing.assert_allclose(stats["nis"], nis, rtol=1e-9)
        np.testing.assert_allclose(stats["logdet_s"], np.linalg.slogdet(ref.S)[1], rtol=1e-9)
    assert np.array_equal(p, np.swapaxes(p, 1, 2))


def test_update_rejects_non_finite_and_indefinite_input() -> None:
    x = np.zeros((2, 2))
    p = np.ascontiguousarray(np.broadcast_to(np.eye(2), (2, 2, 2)))
    h = np.eye(2)
    r = np.array([[[1.0, 0], [0, 1.0]], [[-5.0, 0], [0, 1.0]]])  # member 1: S not PD
    z = np.array([[np.nan, 0.0], [1.0, 1.0]])
    before = p.copy()
    stats = kalman.update(x, p, z, h, r)
    assert not stats["ok"].any()
    np.testing.assert_array_equal(p, before)
    np.testing.assert_array_equal(x, 0.0)


def test_bad_layout_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="C-contiguous float64"):
        kalman.predict(
            np.zeros((2, 3), dtype=np.float32), np.zeros((2, 3, 3)), np.eye(3), np.eye(3)
        )
    with pytest.raises(ValueError, match="does not match"):
        kalman.predict(np.zeros((2, 3)), np.zeros((2, 4, 4)), np.eye(3), np.eye(3))
