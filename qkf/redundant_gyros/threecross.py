r"""Three-cross fault isolation (docs/redundant_gyros.md, "Three-cross").

Three models (gyro subsets, each gyro ideally in two of them) reconstruct the body rate by least
squares from the compensated readings ``y``: ``ω̂_m = (G_mᵀ G_m)⁻¹ G_mᵀ y_m``. The feature is

    T = ‖ω̂₁ − ω̂₂‖ / ‖ω̂₁ − ω̂₃‖.

The rate cancels in the differences, so a fault of gyro i alone gives ``T = T_i``, its
geometric signature (:func:`qkf.redundant_gyros.geometry.signatures`), whatever the fault size
and the body rate. Noise alone also puts T into a band ``|T − T_i| < band`` now and then, with
probability ``p₀ᵢ`` (a property of the geometry and the noise levels only: T is scale free).
The detector counts, over a sliding window of N epochs, the epochs whose T lies in each gyro's
band, and flags gyro i when its count exceeds the binomial ``1 − P_FA / n`` quantile of
``Bin(N, p₀ᵢ)``; among flagged gyros it isolates the one whose count stands highest above its
null mean in standard deviations. The first N − 1 epochs use the shorter windows available.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from qkf.redundant_gyros.geometry import GyroUnit, embedded_ls, signatures

NO_GYRO = -1
"""Isolation result for 'nothing isolated'."""
NULL_SEED = 0x3C05
"""Seed of the Monte Carlo estimate of the no-fault in-band probabilities (deterministic)."""


def model_rates(unit: GyroUnit, y: np.ndarray) -> np.ndarray:
    """LS rate of each model from compensated readings ``y`` (..., n): (..., 3 models, 3)."""
    return np.einsum("mjn,...n->...mj", unit.model_ls, y)


def feature(unit: GyroUnit, y: np.ndarray) -> np.ndarray:
    """Three-cross feature ``‖ω̂₁ − ω̂₂‖ / ‖ω̂₁ − ω̂₃‖`` of readings ``y`` (..., n) (inf when the
    denominator vanishes, NaN when both do)."""
    d12 = y @ (unit.model_ls[0] - unit.model_ls[1]).T
    d13 = y @ (unit.model_ls[0] - unit.model_ls[2]).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.linalg.norm(d12, axis=-1) / np.linalg.norm(d13, axis=-1))


def null_band_probabilities(unit: GyroUnit, samples: int, seed: int = NULL_SEED) -> np.ndarray:
    """Probability that T falls in each gyro's band without a fault (seeded Monte Carlo)."""
    rng = np.random.default_rng(seed)
    hits = np.zeros(unit.n)
    done = 0
    while done < samples:
        m = min(samples - done, 100_000)
        t = feature(unit, rng.standard_normal((m, unit.n)) * unit.comp_noise)
        hits += np.sum(np.abs(t[:, None] - unit.signature) < unit.band, axis=0)
        done += m
    return hits / samples


@dataclass(frozen=True)
class ThreeCrossDetector:
    """The windowed band-count test of one unit (see the module docstring)."""

    unit: GyroUnit
    window: int
    p0: np.ndarray  # (n,) no-fault in-band probabilities, floored at 1 / samples
    threshold: np.ndarray  # (window, n) counts above which gyro i is flagged, per window length

    @classmethod
    def build(
        cls, unit: GyroUnit, window: int, false_alarm: float, samples: int
    ) -> ThreeCrossDetector:
        p0 = np.clip(null_band_probabilities(unit, samples), 1.0 / samples, 1.0 - 1.0 / samples)
        lengths = np.arange(1, window + 1)[:, None]
        thr = stats.binom.ppf(1.0 - false_alarm / unit.n, lengths, p0[None, :])
        return cls(unit, window, p0, np.asarray(thr, dtype=float))

    def isolate(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Feature (B, E) and isolated gyro index (B, E) (``NO_GYRO``: none) of readings
        ``y`` (B, E, n)."""
        t = feature(self.unit, y)
        inband = np.abs(t[..., None] - self.unit.signature) < self.unit.band  # (B, E, n)
        counts = window_sums(inband.astype(np.int32), self.window)
        n_ep = y.shape[1]
        length = np.minimum(np.arange(n_ep) + 1, self.window)  # (E,)
        thr = self.threshold[length - 1]  # (E, n)
        mean = length[:, None] * self.p0
        sd = np.sqrt(mean * (1.0 - self.p0))
        z = np.where(counts > thr, (counts - mean) / sd, -np.inf)
        iso = np.argmax(z, axis=-1)
        flagged = np.isfinite(np.take_along_axis(z, iso[..., None], axis=-1)[..., 0])
        return t, np.where(flagged, iso, NO_GYRO).astype(np.int16)


def window_sums(x: np.ndarray, window: int) -> np.ndarray:
    """Sums over the last ``window`` epochs (axis 1), shorter at the start."""
    c = np.cumsum(x, axis=1)
    if window < x.shape[1]:
        c[:, window:] -= c[:, :-window].copy()
    return c


@dataclass(frozen=True)
class FeatureRow:
    gyro: str
    nominal: float  # signature of the design geometry
    with_errors: float  # the nominal errors left uncompensated


def feature_table(unit: GyroUnit, fault_deg_s: float, rate_deg_s: np.ndarray) -> list[FeatureRow]:
    """Feature value per gyro: from the design axes ``w`` (``nominal``), and from noise-free
    readings that carry the nominal errors uncompensated plus a bias step of ``fault_deg_s`` on
    the gyro, at body rate ``rate_deg_s``, reconstructed with the design axes
    (``with_errors``)."""
    design = np.stack([embedded_ls(unit.w, m) for m in unit.models])
    nominal = signatures(design)
    rows = []
    for i in range(unit.n):
        coeffs = unit.nominal.copy()
        coeffs[i, 0] += fault_deg_s
        m = unit.readings(coeffs, rate_deg_s)
        d12 = (design[0] - design[1]) @ m
        d13 = (design[0] - design[2]) @ m
        with np.errstate(divide="ignore", invalid="ignore"):
            value = float(np.linalg.norm(d12) / np.linalg.norm(d13))
        rows.append(FeatureRow(unit.ids[i], float(nominal[i]), value))
    return rows
