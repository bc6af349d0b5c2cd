"""The batched transfer-alignment environment: N episodes of ``qkf/TransferAlignment-v0``,
``-v1`` or ``-v2`` stepped at once through one batched filter (not N environments in a loop),
as Gymnasium's ``VectorEnv`` (next-step autoreset); what ``gym.make_vec`` returns for these ids.
Sub-environment ``i`` of ``reset(seed=s)`` is the single environment reset with seed ``s + i``,
step for step. Its Stable-Baselines3 twin, over the same batched episodes, is
:class:`envs.transfer_alignment.sb3.BatchedTransferAlignmentSB3Env`.

``render_mode``: ``None`` (default) or ``"rgb_array"``; with the latter every sub-environment
records its episode as the single environment does, and ``render()`` returns one frame per
sub-environment (a tuple of ``(H, W, 3)`` uint8 arrays, as Gymnasium's ``SyncVectorEnv``); a
sub-environment autoreset starts its frame anew.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Unpack

import numpy as np

from envs.common.vector_batched import BatchedVectorEnv
from envs.transfer_alignment.env import calibration_curves, calibration_trace
from envs.transfer_alignment.episodes import EpisodeDriver, EpisodeOptions, StepOutput
from qkf.transfer_alignment.config import Config


class BatchedTransferAlignmentEnv(BatchedVectorEnv[EpisodeDriver]):
    """N transfer-alignment episodes in one batched filter, as a Gymnasium ``VectorEnv``
    (the machinery: :class:`envs.common.vector_batched.BatchedVectorEnv`). The arguments are
    the single environment's, but ``data``."""

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | Config = "paper",
        *,
        render_mode: str | None = None,
        data: object = None,
        **options: Unpack[EpisodeOptions],
    ) -> None:
        if data is not None:  # not silently a simulation instead
            raise ValueError(
                "the batched vector environment does not replay recorded data; use "
                "gym.make(id, data=...) per environment (e.g. in SubprocVecEnv)"
            )
        driver = EpisodeDriver(num_envs, scenario, **options)
        traces = [
            calibration_trace(driver, f"TransferAlignment ({driver.observation_version}) #{i}")
            for i in range(num_envs)
        ]
        super().__init__(driver, traces, render_mode)

    def curves(self, out: StepOutput) -> np.ndarray:
        return calibration_curves(self._driver, out)

    def step_info(self, out: StepOutput) -> dict[str, Any]:
        return {"crlb": out.crlb, "t_s": out.t_s}
