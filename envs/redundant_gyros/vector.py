"""The batched redundant-gyro environment: N episodes of ``qkf/RedundantGyroCalibration-v*``
stepped at once through the compiled UKF (one call per period for all of them, parallel over
episodes), as Gymnasium's ``VectorEnv`` (next-step autoreset); what ``gym.make_vec`` returns
for these ids. Sub-environment ``i`` of ``reset(seed=s)`` is the single environment reset with
seed ``s + i``, step for step. Its Stable-Baselines3 twin over the same batched episodes is
:class:`envs.redundant_gyros.sb3.BatchedGyroSB3Env`.

``render_mode``: ``None`` (default) or ``"rgb_array"`` (one frame per sub-environment, as the
single environment's ``render()``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Unpack

import numpy as np

from envs.common.vector_batched import BatchedVectorEnv
from envs.redundant_gyros.env import gyro_curves, gyro_trace
from envs.redundant_gyros.episodes import GyroEpisodes, GyroOptions, GyroStep
from qkf.redundant_gyros.config import GyrosConfig


class BatchedGyroCalibrationEnv(BatchedVectorEnv[GyroEpisodes]):
    """N gyro-calibration episodes in one batched compiled UKF, as a Gymnasium ``VectorEnv``
    (the machinery: :class:`envs.common.vector_batched.BatchedVectorEnv`). The arguments are
    the single environment's."""

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | GyrosConfig | None = None,
        *,
        render_mode: str | None = None,
        **options: Unpack[GyroOptions],
    ) -> None:
        self.episodes = GyroEpisodes(num_envs, scenario, **options)
        title = f"RedundantGyroCalibration ({self.episodes.observation_version})"
        traces = [gyro_trace(self.episodes, f"{title} #{i}") for i in range(num_envs)]
        super().__init__(self.episodes, traces, render_mode)

    def curves(self, out: GyroStep) -> np.ndarray:
        return gyro_curves(self.episodes, out.errors)

    def step_info(self, out: GyroStep) -> dict[str, Any]:
        return {"t_s": out.t_s, "onset_s": self.episodes.onset_s.copy()}

    def reset_info(self) -> dict[str, Any]:
        return {"onset_s": self.episodes.onset_s.copy()}
