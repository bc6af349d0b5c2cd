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
5.   innovation log-likelihood per epoch and measurement row, relative to the nominal (κ = 1)
     filter run from the same state over the period;
6.   elapsed fraction of the episode;  7. |ω̂| in deg/s;  8. κ index scaled to [0, 1].

Rewards (``reward=``): ``likelihood`` (default, no truth, as the QKF's:
``(ℓ_agent − ℓ_nominal) / T_c``), ``oracle`` (minus the period's mean of ``‖Δp‖ / ‖σ_CRLB,p‖``)
or ``nees`` (minus ``|mean NEES / 15 − 1|`` over the period).

``info`` carries the true errors at the end of the period in display units (``errors``: 15
values in SPEC §8 order), the CRLB there (``crlb``), ``kappa``, ``t_s`` and ``diverged``. A
filter that goes non-finite ends the episode (``terminated=True``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from envs.episodes import OBS_LIMIT, OBS_SIZE, BatchedEpisodes, RewardKind, StepOutput
from qkf.transfer_alignment.config import Config, load_config

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def resolve_scenario(scenario: str | Path | Config, overrides: list[str] | None = None) -> Config:
    """A preset name (``thermal_snap``), a config path, or a ``Config`` as it is."""
    if isinstance(scenario, Config):
        return scenario
    path = Path(scenario)
    if not path.suffix:
        path = CONFIGS / f"{str(scenario).replace('-', '_')}.yaml"
    return load_config(path, overrides or [])


class ActionMap:
    """Actions → κ, for both action types; invalid actions raise ``ValueError``."""

    def __init__(self, kappas: np.ndarray, action_type: str) -> None:
        if action_type not in ("discrete", "continuous"):
            raise ValueError(f"action_type must be 'discrete' or 'continuous', not {action_type!r}")
        self.kappas = kappas
        self.log_kappa = np.log10(kappas)
        self.action_type = action_type
        self.space: spaces.Space[Any] = (
            spaces.Discrete(kappas.size)
            if action_type == "discrete"
            else spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        )

    def __call__(self, action: Any) -> tuple[float, float]:
        """κ and its position in [0, 1] on the action scale."""
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


class Driver:
    """What the environment front ends share: the config, the action map, the batched episodes
    and one generator per episode (each episode's data is drawn from its own generator)."""

    def __init__(
        self,
        n: int,
        scenario: str | Path | Config,
        action_type: str,
        reward: str,
        overrides: list[str] | None,
    ) -> None:
        if n < 1:
            raise ValueError("num_envs must be at least 1")
        if reward not in ("likelihood", "oracle", "nees"):
            raise ValueError(f"reward must be likelihood, oracle or nees, not {reward!r}")
        self.cfg = resolve_scenario(scenario, overrides)
        self.actions = ActionMap(np.asarray(self.cfg.adaptive.actions.values()), action_type)
        self.observation_space = spaces.Box(
            -OBS_LIMIT, OBS_LIMIT, shape=(OBS_SIZE,), dtype=np.float32
        )
        self.core = BatchedEpisodes(self.cfg, n, reward)  # type: ignore[arg-type]
        self.rngs = [seeding.np_random()[0] for _ in range(n)]

    def reset_env(self, i: int) -> np.ndarray:
        """Start episode ``i`` anew from its generator; its first observation."""
        return self.core.reset(i, int(self.rngs[i].integers(2**63 - 1)))

    def step(self, actions: Any) -> StepOutput:
        """Map one action per episode to κ and run one decision period in all of them."""
        mapped = [self.actions(a) for a in actions]
        return self.core.step(np.array([m[0] for m in mapped]), np.array([m[1] for m in mapped]))


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
        self._driver = Driver(1, scenario, action_type, reward, overrides)
        self.cfg = self._driver.cfg
        self.actions = self._driver.actions
        self.action_space = self.actions.space
        self.observation_space = self._driver.observation_space
        self._started = False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._driver.rngs[0] = self.np_random
        obs = self._driver.reset_env(0)
        self._started = True
        return obs, {"kappa": 1.0, "diverged": False}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        kappa, _ = self.actions(action)
        out = self._driver.step([action])
        info = {
            "kappa": kappa,
            "diverged": bool(out.terminated[0]),
            "errors": out.errors[0],
            "crlb": out.crlb[0],
            "t_s": float(out.t_s[0]),
        }
        return (
            out.obs[0],
            float(out.reward[0]),
            bool(out.terminated[0]),
            bool(out.truncated[0]),
            info,
        )
