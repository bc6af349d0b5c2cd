"""The batched transfer-alignment environment as a Stable-Baselines3 ``VecEnv``.

The same batched episodes as :class:`envs.transfer_alignment.vector.BatchedTransferAlignmentEnv`
(Gymnasium's ``VectorEnv``), with SB3's API: same-step autoreset, so when an episode ends
``step_wait`` returns the first observation of the next episode and puts the last one in
``info["terminal_observation"]`` (with ``info["TimeLimit.truncated"]`` for the time limit).
Sub-environment ``i`` seeded with ``s`` draws the same episodes as ``TransferAlignmentEnv``
reset with seed ``s + i``. What ``qkf train`` trains on for these ids
(``envs.ENVIRONMENTS[id].sb3_vec_env``). The SB3 machinery is
:class:`envs.common.sb3_batched.BatchedSB3VecEnv`'s. Importing this module imports
Stable-Baselines3 (and torch), which ``import envs`` does not.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from envs.common.sb3_batched import BatchedSB3VecEnv
from envs.transfer_alignment.episodes import DEFAULT_PERIOD_S, EpisodeDriver
from qkf.transfer_alignment.config import Config


class BatchedTransferAlignmentSB3Env(BatchedSB3VecEnv):
    """N transfer-alignment episodes in one batched filter, as an SB3 ``VecEnv``."""

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str = "likelihood",
        overrides: list[str] | None = None,
        period_s: float = DEFAULT_PERIOD_S,
        observation: str = "v0",
        controls: str | None = None,
        base: str | None = None,
        expert: str | None = None,
    ) -> None:
        driver = EpisodeDriver(
            num_envs, scenario, action_type, reward, overrides, period_s, observation,
            controls=controls, base=base, expert=expert,
        )  # fmt: skip
        self.cfg = driver.cfg
        self.actions = driver.actions
        vector = driver.actions.action_type == "continuous" or driver.controls is not None
        super().__init__(
            driver, num_envs, driver.observation_space, driver.action_space, vector_actions=vector
        )

    def expert_actions(self) -> np.ndarray:
        """The expert's actions for every episode's next period (``expert=``, v4):
        :mod:`envs.transfer_alignment.experts`, what :func:`agents.imitation.dagger` asks."""
        return np.asarray(self._driver.expert_actions())
