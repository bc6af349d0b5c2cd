r"""Gymnasium environment ``qkf/TransferAlignment-v0`` (SPEC §5).

One episode is one realisation of a scenario (truth and noise drawn from ``np_random`` at
reset); one step is one decision period ``T_c`` (10 filter epochs by default) in which the
transfer-alignment filter runs with the process-noise factor the agent chose.

Actions: ``Discrete(A)``, an index into the κ action set (default 11 values 0.01 … 100), or,
with ``action_type="continuous"``, ``Box(-1, 1, (1,))`` mapped linearly to
``log10 κ ∈ [log10 κ_min, log10 κ_max]``.

Observation (float32, 9 values, roughly unit scale):

0–2. mean ``log10(σ / σ₀)`` of the attitude, bias and calibration blocks of P (σ₀: prior);
3–4. mean NIS of the attitude rows and of the rate rows over the period, divided by 3;
5.   innovation log-likelihood per epoch relative to that of the nominal (κ = 1) filter run
     from the same state over the period, per measurement row;
6.   elapsed fraction of the episode;  7. |ω̂| in deg/s;  8. κ index scaled to [0, 1].

Rewards (``reward=``): ``likelihood`` (default, no truth, as the QKF's:
``(ℓ_agent − ℓ_nominal) / T_c``), ``oracle`` (minus the period's mean of ``‖Δp‖ / ‖σ_CRLB,p‖``)
or ``nees`` (minus ``|mean NEES / 15 − 1|`` over the period).

``info`` carries the true errors at the end of the period in display units
(``errors``: 15 values, SPEC §8 order), the CRLB there (``crlb``), ``kappa`` and ``diverged``.
A filter that goes non-finite ends the episode (``terminated=True``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from qkf.config import Config, load_config
from qkf.crlb import crlb
from qkf.filters import FilterParams, TransferAlignmentKF
from qkf.metrics import nees, state_errors
from qkf.scenario import ScenarioData, n_epochs, simulate
from qkf.states import DISPLAY_UNIT

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
OBS_SIZE = 9
OBS_LIMIT = 100.0  # observations are clipped to ±this (they are of order one in practice)
RewardKind = Literal["likelihood", "oracle", "nees"]


def resolve_scenario(scenario: str | Path | Config, overrides: list[str] | None = None) -> Config:
    """A preset name (``thermal_snap``), a config path, or a ``Config`` as it is."""
    if isinstance(scenario, Config):
        return scenario
    path = Path(scenario)
    if not path.suffix:
        path = CONFIGS / f"{str(scenario).replace('-', '_')}.yaml"
    return load_config(path, overrides or [])


class TransferAlignmentEnv(gym.Env[np.ndarray, Any]):
    """Choose the filter's process-noise factor every decision period (see module docstring)."""

    metadata = {"render_modes": []}  # noqa: RUF012 - Gymnasium's convention

    def __init__(
        self,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: RewardKind = "likelihood",
        overrides: list[str] | None = None,
    ) -> None:
        if action_type not in ("discrete", "continuous"):
            raise ValueError(f"action_type must be 'discrete' or 'continuous', not {action_type!r}")
        if reward not in ("likelihood", "oracle", "nees"):
            raise ValueError(f"reward must be likelihood, oracle or nees, not {reward!r}")
        self.cfg = resolve_scenario(scenario, overrides)
        self.action_type = action_type
        self.reward_kind = reward
        self.kappas = np.asarray(self.cfg.adaptive.actions.values())
        self.log_kappa = np.log10(self.kappas)
        self.period = max(1, round(self.cfg.adaptive.qkf.period_s / self.cfg.scenario.dt_s))
        self.n_epochs = n_epochs(self.cfg.scenario)
        self.max_steps = -(-self.n_epochs // self.period)
        if action_type == "discrete":
            self.action_space: spaces.Space[Any] = spaces.Discrete(self.kappas.size)
        else:
            self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.observation_space = spaces.Box(
            -OBS_LIMIT, OBS_LIMIT, shape=(OBS_SIZE,), dtype=np.float32
        )
        self._params = FilterParams.from_config(self.cfg)
        self._bound = crlb(self.cfg).bound  # (N, 15) SI, used by the oracle reward and info
        self._data: ScenarioData | None = None
        self._kf: TransferAlignmentKF | None = None
        self._k = 0
        self._kappa_index = 0.0

    # -- helpers ----------------------------------------------------------------------------
    def kappa_of(self, action: Any) -> tuple[float, float]:
        """κ and its index position in [0, 1] for an action; raises on invalid actions."""
        if self.action_type == "discrete":
            a = np.asarray(action)
            v = a.reshape(-1)[0] if a.size == 1 else None
            integral = v is not None and (
                np.issubdtype(a.dtype, np.integer)
                or (
                    np.issubdtype(a.dtype, np.floating) and np.isfinite(v) and float(v).is_integer()
                )
            )
            if not integral:
                raise ValueError(f"discrete action must be an integer index, got {action!r}")
            i = int(v)  # type: ignore[arg-type]
            if not 0 <= i < self.kappas.size:
                raise ValueError(f"action {i} outside 0..{self.kappas.size - 1}")
            return float(self.kappas[i]), i / (self.kappas.size - 1)
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.size != 1 or not np.isfinite(a[0]) or abs(a[0]) > 1.0 + 1e-6:
            raise ValueError(
                f"continuous action must be one finite value in [-1, 1], got {action!r}"
            )
        u = (float(np.clip(a[0], -1.0, 1.0)) + 1.0) / 2.0
        lo, hi = self.log_kappa[0], self.log_kappa[-1]
        return float(10.0 ** (lo + u * (hi - lo))), u

    def _observe(self, rec: Any, rec_nominal: Any) -> np.ndarray:
        assert self._kf is not None
        p0 = self._params.p0_sigma
        log_ratio = 0.5 * np.log10(rec.var[0, -1] / p0**2)
        nis_att = np.nanmean(rec.nis_att[0]) / 3.0 if np.isfinite(rec.nis_att[0]).any() else 0.0
        nis_rate = np.nanmean(rec.nis_rate[0]) / 3.0 if np.isfinite(rec.nis_rate[0]).any() else 0.0
        rows = self._params.n_meas
        ll_gain = (rec.loglik[0].sum() - rec_nominal.loglik[0].sum()) / (rec.loglik.shape[1] * rows)
        obs = np.array(
            [
                log_ratio[0:3].mean(),
                log_ratio[3:6].mean(),
                log_ratio[6:15].mean(),
                nis_att,
                nis_rate,
                ll_gain,
                self._k / self.n_epochs,
                np.linalg.norm(rec.rate[0, -1]) / (np.pi / 180.0),
                self._kappa_index,
            ]
        )
        obs = np.nan_to_num(obs, nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
        return np.clip(obs, -OBS_LIMIT, OBS_LIMIT).astype(np.float32)

    # -- Gymnasium API ----------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        episode_seed = int(self.np_random.integers(2**63 - 1))
        self._data = simulate(self.cfg, episode_seed, [0])
        self._kf = TransferAlignmentKF(self._params, 1)
        self._kf.initialize(self._data.ads_q[:, 0])
        self._k = 0
        self._kappa_index = float(np.argmin(np.abs(self.log_kappa)) / (self.kappas.size - 1))
        obs = np.zeros(OBS_SIZE, dtype=np.float32)
        obs[8] = self._kappa_index
        return obs, {"kappa": 1.0, "diverged": False}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._kf is None or self._data is None:
            raise RuntimeError("call reset() before step()")
        kappa, self._kappa_index = self.kappa_of(action)
        k0, k1 = self._k, min(self.n_epochs, self._k + self.period)
        nominal = self._kf.copy()
        rec = self._kf.step_data(
            self._data, k0, k1, kappa=kappa, record_cov=self.reward_kind == "nees"
        )
        rec_nom = nominal.step_data(self._data, k0, k1, kappa=1.0)
        self._k = k1
        d = self._data
        err = state_errors(rec.est, d.q_true[k0:k1], d.bias[:, k0:k1], d.calib[:, k0:k1])[0]
        diverged = bool(self._kf.diverged[0])
        if diverged:
            reward = -1e3
        elif self.reward_kind == "likelihood":
            reward = float((rec.loglik[0].sum() - rec_nom.loglik[0].sum()) / ((k1 - k0) * d.dt))
        elif self.reward_kind == "oracle":
            ratio = np.linalg.norm(err[:, 6:15], axis=1) / np.linalg.norm(
                self._bound[k0:k1, 6:15], axis=1
            )
            reward = -float(ratio.mean())
        else:
            assert rec.cov is not None
            reward = -float(abs(np.mean(nees(err, rec.cov[0])) / 15.0 - 1.0))
        obs = self._observe(rec, rec_nom)
        terminated = diverged
        truncated = (not diverged) and self._k >= self.n_epochs
        info = {
            "kappa": kappa,
            "diverged": diverged,
            "errors": err[-1] / DISPLAY_UNIT,
            "crlb": self._bound[k1 - 1] / DISPLAY_UNIT,
            "t_s": float(d.t[k1 - 1]),
        }
        return obs, reward, terminated, truncated, info
