r"""Transfer-alignment Kalman filter: 15 error states, batched over trials (docs/models.md).

Each epoch ``k``, for every trial:

1. rate estimate ``A = (I + K(p̂))⁻¹``, ``ω̂ = A (ω̃_k − b̂)``;
2. if the ADS measured at ``k``: innovation ``z_a = Log(Ĉᵀ C_ADS)`` (and, with rate matching,
   ``z_r = ω_ADS − ω̂``), Joseph-form update with ``H_a = [I, 0, 0]``,
   ``H_r = [0, −A, −A Ω(ω̂)]``, ``R_a = σ_a² I``, ``R_r = σ_r² I + σ_v² A Aᵀ / Δt``; then the
   reset ``Ĉ ← Ĉ Exp(δθ̂)``, ``b̂ += Δb̂``, ``p̂ += Δp̂`` and a fresh ``ω̂``;
3. propagation over ``Δt``: ``Ĉ ← Ĉ Exp(ω̂ Δt)``, ``P ← Φ P Φᵀ + Q_d(κ q_p0)`` with the exact
   ``Φ`` and ``Q_d`` of :mod:`qkf.transfer_alignment.model`.

Rate matching and correlated noise. The gyro noise ``η_k`` of epoch ``k`` is in the rate
innovation ``z_r,k`` (that is why ``R_r`` holds ``σ_v² A Aᵀ/Δt``) and it also drives the attitude
error over the step ``k → k+1`` (``w_θ = −Γ A η_k``). Treating the two as independent counts the
same noise twice and makes the filter over-confident in bias and calibration (measured: NEES
about 1.4 per bias state, see the tests). With ``rate_noise_correlation`` (default) the
prediction uses the cross-covariance ``C = Γ A (σ_v²/Δt) Aᵀ`` between the attitude process noise
and the rate rows, the textbook correlated-noise prediction::

    x̂⁻_{k+1} = Φ x̂⁺_k + C S⁻¹ ν,   P⁻_{k+1} = Φ P⁺ Φᵀ + Q − Φ K Cᵀ − C Kᵀ Φᵀ − C S⁻¹ Cᵀ

Switch it off (``filter.rate_noise_correlation: false``) for the uncorrelated filter.

The process-noise factor ``κ`` may differ per trial and per epoch: adaptive filters and the
Gymnasium environment drive it. A trial whose numbers go non-finite (or whose covariance loses
positive definiteness) is flagged in :attr:`TransferAlignmentKF.diverged` and frozen; its records
are NaN from then on.

The work is done by a compiled kernel (``_ta_kernel``) that runs a block of epochs per call,
trials in parallel; the covariance is stored scaled by the prior sigmas.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Protocol, cast

import numba as nb
import numpy as np

import qkf.core.jit  # noqa: F401  (binds compiled callees locally: docs/performance.md)
from qkf.core.jit import SERIAL_BELOW, kernel_array
from qkf.transfer_alignment import kernel as _ta_kernel
from qkf.transfer_alignment.model import gauss_legendre
from qkf.transfer_alignment.params import FilterParams


class SensorData(Protocol):
    """What :meth:`TransferAlignmentKF.step_data` reads (a ``ScenarioData`` or recorded data)."""

    @property
    def gyro(self) -> np.ndarray: ...  # (B, N, 3) rad/s
    @property
    def ads_q(self) -> np.ndarray: ...  # (B, N, 4) scalar-last
    @property
    def ads_rate(self) -> np.ndarray: ...  # (B, N, 3) rad/s
    @property
    def has_meas(self) -> np.ndarray: ...  # (N,) or (B, N) bool


@dataclass
class FilterRecord:
    """Per-epoch output of a block of epochs, trials on axis 0, epochs on axis 1 (SI units)."""

    est: np.ndarray  # (B, n, 16): q̂ (4, scalar-last), b̂ (3), p̂ (9) after the update
    var: np.ndarray  # (B, n, 15): diagonal of P after the update
    cov: np.ndarray | None  # (B, n, 15, 15) when asked for
    dx: np.ndarray  # (B, n, 15): correction applied by the update (0 if none)
    innov: np.ndarray  # (B, n, 6): innovation (attitude, rate); NaN where absent
    nis_att: np.ndarray  # (B, n): z_aᵀ S_aa⁻¹ z_a (NaN without measurement)
    nis_rate: np.ndarray  # (B, n): z_rᵀ S_rr⁻¹ z_r (NaN without rate matching)
    nis: np.ndarray  # (B, n): νᵀ S⁻¹ ν over all rows
    logdet_s: np.ndarray  # (B, n): log det S, S in SI
    trace_s_att: np.ndarray  # (B, n): trace of the attitude block of S, rad²
    rate: np.ndarray  # (B, n, 3): ω̂ used for propagation

    @property
    def loglik(self) -> np.ndarray:
        """Innovation log-likelihood ``ℓ = −½ (νᵀS⁻¹ν + log det S)`` per epoch (no 2π term).

        0 at epochs without a measurement; −inf once the trial has diverged.
        """
        out = np.empty(self.nis.shape)
        # the stats' columns are strided views; one array type compiles the routine once
        nis, logdet, est = (
            kernel_array(a, float, a.shape) for a in (self.nis, self.logdet_s, self.est)
        )
        _loglik_into(nis, logdet, est, out)
        return out


@nb.njit(cache=True)
def _loglik_into(nis: np.ndarray, logdet: np.ndarray, est: np.ndarray, out: np.ndarray) -> None:
    """:attr:`FilterRecord.loglik` into ``out`` (B, n): one compiled call instead of seven
    numpy ones, for the single environment's two records per step (docs/performance.md).
    Without fast-math: the numbers of ``−0.5 * (nis + logdet)`` in numpy."""
    for i in range(nis.shape[0]):
        for k in range(nis.shape[1]):
            finite = True
            for j in range(est.shape[2]):
                finite = finite and np.isfinite(est[i, k, j])
            if not finite:  # diverged
                out[i, k] = -np.inf
            elif np.isnan(nis[i, k]):  # no measurement
                out[i, k] = 0.0
            else:
                out[i, k] = -0.5 * (nis[i, k] + logdet[i, k])


class TransferAlignmentKF:
    """The 15-state transfer-alignment filter for ``n_trials`` independent trials at once.

    Use :meth:`initialize` with the first ADS attitude, then :meth:`step` over blocks of epochs.
    """

    def __init__(self, params: FilterParams, n_trials: int) -> None:
        if n_trials < 1:
            raise ValueError("n_trials must be at least 1")
        self.params = params
        self.n_trials = n_trials
        self._d = np.ascontiguousarray(params.p0_sigma, dtype=float)
        k = params.quadrature_nodes
        self._gl_s = np.zeros((k - 1, k))
        self._gl_w = np.zeros((k - 1, k))
        for n in range(2, k + 1):
            self._gl_s[n - 2, :n], self._gl_w[n - 2, :n] = gauss_legendre(n)
        self.q_hat = np.zeros((n_trials, 4))
        self.q_hat[:, 3] = 1.0
        self.b_hat = np.zeros((n_trials, 3))
        self.p_hat = np.zeros((n_trials, 9))
        self._pt = np.broadcast_to(np.eye(15), (n_trials, 15, 15)).copy()
        self.diverged = np.zeros(n_trials, dtype=bool)
        self.sigma_a = np.full(n_trials, params.sigma_a)
        """Attitude measurement sigma (rad) the filter assumes, per trial; adaptive-R methods
        change it between calls."""
        self.q_scale = np.ones((n_trials, 2))
        """Factors on the attitude (σ_v²) and bias (σ_u²) process noise, per trial (B, 2); the
        calibration block's are ``kappa`` of :meth:`step`. The ``blocks`` moves of the
        environments change them between calls (docs/environment.md, "Controls")."""
        self._constants: tuple[FilterParams, _ta_kernel.ConstantsTuple] | None = None  # see step

    def initialize(self, ads_q0: np.ndarray) -> None:
        """Start from ``Ĉ_0`` = first ADS attitude (B, 4), ``b̂ = 0``, ``p̂ = 0``, ``P = P_0``."""
        q0 = np.asarray(ads_q0, dtype=float)
        if q0.shape != (self.n_trials, 4):
            raise ValueError(f"ads_q0 must have shape ({self.n_trials}, 4), got {q0.shape}")
        self.q_hat[:] = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
        self.b_hat[:] = 0.0
        self.p_hat[:] = 0.0
        self._pt[:] = np.eye(15)
        self.diverged[:] = False
        self.sigma_a[:] = self.params.sigma_a
        self.q_scale[:] = 1.0

    @property
    def P(self) -> np.ndarray:
        """Covariance (B, 15, 15) in SI."""
        return self._pt * np.outer(self._d, self._d)

    @P.setter
    def P(self, value: np.ndarray) -> None:
        value = np.asarray(value, dtype=float)
        self._pt[:] = value / np.outer(self._d, self._d)

    def copy(self) -> TransferAlignmentKF:
        """An independent copy (state and covariance), e.g. for an explorative filter."""
        return copy.deepcopy(self)

    def load_trial(self, i: int | slice, other: TransferAlignmentKF, j: int | slice = 0) -> None:
        """Overwrite trial(s) ``i`` with trial(s) ``j`` of ``other`` (estimates, covariance,
        flags, assumed attitude noise, process-noise factors)."""
        self.q_hat[i] = other.q_hat[j]
        self.b_hat[i] = other.b_hat[j]
        self.p_hat[i] = other.p_hat[j]
        self._pt[i] = other._pt[j]
        self.diverged[i] = other.diverged[j]
        self.sigma_a[i] = other.sigma_a[j]
        self.q_scale[i] = other.q_scale[j]

    def copy_state_from(self, other: TransferAlignmentKF) -> None:
        """Overwrite this filter's estimates, covariance and divergence flags with ``other``'s."""
        if other.n_trials != self.n_trials:
            raise ValueError("filters of different batch sizes")
        self.load_trial(slice(None), other, slice(None))

    def _kernel_state(self) -> _ta_kernel.StateTuple:
        """The filter's arrays the kernel updates in place, the fields of
        :class:`~qkf.transfer_alignment.kernel.FilterState` as a plain tuple."""
        return (self.q_hat, self.b_hat, self.p_hat, self._pt, self.diverged)

    def _kernel_constants(self) -> _ta_kernel.ConstantsTuple:
        """The kernel's constants of :attr:`params`, the fields of
        :class:`~qkf.transfer_alignment.kernel.Constants` as a plain tuple, built once per
        parameter set."""
        p = self.params
        if self._constants is not None and self._constants[0] is p:
            return self._constants[1]
        named = _ta_kernel.Constants(
            dt=float(p.dt),
            sigma_v=float(p.sigma_v),
            sigma_u=float(p.sigma_u),
            qp0=float(p.qp0),
            sigma_r=float(p.sigma_r),
            use_rate=bool(p.use_rate),
            correlated=bool(p.rate_noise_correlation),
            d=self._d,
            gl_s=self._gl_s,
            gl_w=self._gl_w,
        )
        constants = cast(_ta_kernel.ConstantsTuple, tuple(named))
        self._constants = (p, constants)
        return constants

    def step(
        self,
        gyro: np.ndarray,
        ads_q: np.ndarray,
        ads_rate: np.ndarray,
        has_meas: np.ndarray,
        kappa: float | np.ndarray = 1.0,
        record_cov: bool = False,
    ) -> FilterRecord:
        """Run ``n`` epochs for every trial and return what happened.

        ``gyro``, ``ads_rate`` (B, n, 3) rad/s; ``ads_q`` (B, n, 4); ``has_meas`` (n,) or
        (B, n) bool;
        ``kappa``: process-noise factors, ``q_p = κ · q_p0``, see :func:`expand_kappa`.
        """
        b = self.n_trials
        gyro = _block(gyro, b, 3, "gyro")
        n = gyro.shape[1]
        ads_q = _block(ads_q, b, 4, "ads_q", n)
        ads_rate = _block(ads_rate, b, 3, "ads_rate", n)
        has_meas = kernel_array(has_meas, bool, (b, n))  # one compiled kernel, not two
        kap = expand_kappa(kappa, b, n)
        # the fields of kernel.Records, in order; axis 1 of cov empty: not recorded
        rec = (
            np.empty((b, n, 16)),  # est
            np.empty((b, n, 15)),  # var
            np.empty((b, n if record_cov else 0, 15, 15)),  # cov
            np.empty((b, n, 15)),  # dx
            np.empty((b, n, 6)),  # innov
            np.empty((b, n, 5)),  # stats
            np.empty((b, n, 3)),  # rate
        )
        state = self._kernel_state()
        inputs = (
            gyro, ads_q, ads_rate, has_meas, kap,
            np.ascontiguousarray(self.sigma_a, float), np.ascontiguousarray(self.q_scale, float),
        )  # fmt: skip
        # A single environment's step calls this twice per decision period of ten epochs, so
        # the wrapper is kept to a few microseconds: the constants are built once per
        # parameter set, and the serial kernel takes plain tuples (docs/performance.md).
        if b >= SERIAL_BELOW:
            _ta_kernel.run_block(
                _ta_kernel.FilterState(*state),
                _ta_kernel.Inputs(*inputs),
                _ta_kernel.Constants(*self._kernel_constants()),
                _ta_kernel.Records(*rec),
            )
        else:
            _ta_kernel.run_block_serial(state, inputs, self._kernel_constants(), rec)
        est, var, cov, dx, innov, stats, rate = rec
        return FilterRecord(
            est=est,
            var=var,
            cov=cov if record_cov else None,
            dx=dx,
            innov=innov,
            nis_att=stats[..., 0],
            nis_rate=stats[..., 1],
            nis=stats[..., 2],
            logdet_s=stats[..., 3],
            trace_s_att=stats[..., 4],
            rate=rate,
        )

    def step_data(
        self,
        data: SensorData,
        start: int,
        stop: int,
        kappa: float | np.ndarray = 1.0,
        record_cov: bool = False,
    ) -> FilterRecord:
        """:meth:`step` over epochs ``[start, stop)`` of simulated data."""
        sl = slice(start, stop)
        return self.step(
            data.gyro[:, sl],
            data.ads_q[:, sl],
            data.ads_rate[:, sl],
            data.has_meas[..., sl],
            kappa,
            record_cov,
        )


def expand_kappa(kappa: float | np.ndarray, n_trials: int, n_epochs: int) -> np.ndarray:
    """Broadcast process-noise factors to (B, n, 9): one per trial, epoch and calibration term.

    Accepts a scalar, (B,), (B, n) or (B, n, 9). Raises ``ValueError`` for anything else and for
    non-finite or non-positive values.
    """
    if isinstance(kappa, float | int):  # a scalar: checked before it is spread
        if not (np.isfinite(kappa) and kappa > 0.0):
            raise ValueError("kappa must be finite and positive")
        return np.full((n_trials, n_epochs, 9), float(kappa))
    kap = np.asarray(kappa, dtype=float)
    if kap.ndim == 1:
        kap = kap[:, None, None]
    elif kap.ndim == 2:
        kap = kap[:, :, None]
    out = np.empty((n_trials, n_epochs, 9))
    try:
        out[...] = kap  # broadcast into a fresh contiguous array
    except ValueError:
        raise ValueError(
            f"kappa of shape {np.shape(kappa)} does not fit (B={n_trials}, n={n_epochs}[, 9])"
        ) from None
    # the given factors are checked, not their broadcast copy (the same values, fewer of them)
    if not (np.isfinite(kap).all() and (kap > 0.0).all()):
        raise ValueError("kappa must be finite and positive")
    return out


def _block(arr: np.ndarray, b: int, width: int, name: str, n: int | None = None) -> np.ndarray:
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[0] != b or arr.shape[2] != width:
        raise ValueError(f"{name} must have shape ({b}, n, {width}), got {arr.shape}")
    if n is not None and arr.shape[1] != n:
        raise ValueError(f"{name} covers {arr.shape[1]} epochs, expected {n}")
    return np.ascontiguousarray(arr)
