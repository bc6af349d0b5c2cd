"""The batched redundant-gyro environment as a Stable-Baselines3 ``VecEnv``.

The same batched episodes as :class:`envs.redundant_gyros.vector.BatchedGyroCalibrationEnv`,
with SB3's API: same-step autoreset, so when an episode ends ``step_wait`` returns the first
observation of the next episode and puts the last one in ``info["terminal_observation"]``
(with ``info["TimeLimit.truncated"]``). Sub-environment ``i`` seeded with ``s`` draws the same
episodes as ``RedundantGyroCalibrationEnv`` reset with seed ``s + i``. What ``qkf train``
trains on for these ids (``envs.ENVIRONMENTS[id].sb3_vec_env``). The SB3 machinery is
:class:`envs.common.sb3_batched.BatchedSB3VecEnv`'s. Importing this module imports
Stable-Baselines3 (and torch), which ``import envs`` does not.
"""

from __future__ import annotations

from pathlib import Path
from typing import Unpack

from envs.common.sb3_batched import BatchedSB3VecEnv
from envs.redundant_gyros.episodes import GyroEpisodes, GyroOptions
from qkf.redundant_gyros.config import GyrosConfig


class BatchedGyroSB3Env(BatchedSB3VecEnv[GyroEpisodes]):
    """N gyro-calibration episodes in one batched compiled UKF, as an SB3 ``VecEnv``. The
    arguments are the single environment's, but ``render_mode``."""

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | GyrosConfig | None = None,
        **options: Unpack[GyroOptions],
    ) -> None:
        self.episodes = GyroEpisodes(num_envs, scenario, **options)
        continuous = self.episodes.actions.action_type == "continuous"
        super().__init__(self.episodes, vector_actions=continuous)
