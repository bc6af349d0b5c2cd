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
from typing import Unpack

import numpy as np

from envs.common.sb3_batched import BatchedSB3VecEnv
from envs.transfer_alignment.episodes import EpisodeDriver, EpisodeOptions
from qkf.transfer_alignment.config import Config


class BatchedTransferAlignmentSB3Env(BatchedSB3VecEnv[EpisodeDriver]):
    """N transfer-alignment episodes in one batched filter, as an SB3 ``VecEnv``. The
    arguments are the single environment's, but ``render_mode`` and ``data``."""

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | Config = "paper",
        **options: Unpack[EpisodeOptions],
    ) -> None:
        driver = EpisodeDriver(num_envs, scenario, **options)
        vector = driver.actions.action_type == "continuous" or driver.controls is not None
        super().__init__(driver, vector_actions=vector)

    def expert_actions(self) -> np.ndarray:
        """The expert's actions for every episode's next period (``expert=``, v4):
        :mod:`envs.transfer_alignment.experts`, what :func:`agents.imitation.dagger` asks."""
        return np.asarray(self._driver.expert_actions())
