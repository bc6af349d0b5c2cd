"""Gymnasium environments of qkf, registered as ``qkf/...`` on import (docs/environment.md).

``qkf/TransferAlignment-v0`` wraps the transfer-alignment filter: the agent picks the
process-noise factor κ every decision period. The episode length follows the config (the
environment truncates itself), so no ``max_episode_steps`` is registered.
``qkf/RedundantGyroCalibration-v0`` asks the same of the redundant-gyro calibration UKF
(docs/redundant_gyros.md).
"""

from gymnasium.envs.registration import register, registry

from envs.episodes import ActionMap, BatchedEpisodes, EpisodeDriver
from envs.redundant_gyro import GYRO_REWARDS, RedundantGyroCalibrationEnv
from envs.rewards import REWARDS, PeriodOutcome, Reward
from envs.transfer_alignment import TransferAlignmentEnv
from envs.vector import TransferAlignmentVectorEnv

ENV_ID = "qkf/TransferAlignment-v0"

if ENV_ID not in registry:
    register(
        id=ENV_ID,
        entry_point="envs.transfer_alignment:TransferAlignmentEnv",
        vector_entry_point="envs.vector:TransferAlignmentVectorEnv",
        max_episode_steps=None,
    )

GYRO_ENV_ID = "qkf/RedundantGyroCalibration-v0"

if GYRO_ENV_ID not in registry:
    register(
        id=GYRO_ENV_ID,
        entry_point="envs.redundant_gyro:RedundantGyroCalibrationEnv",
        max_episode_steps=None,
    )

__all__ = [
    "ENV_ID",
    "GYRO_ENV_ID",
    "GYRO_REWARDS",
    "REWARDS",
    "ActionMap",
    "BatchedEpisodes",
    "EpisodeDriver",
    "PeriodOutcome",
    "RedundantGyroCalibrationEnv",
    "Reward",
    "TransferAlignmentEnv",
    "TransferAlignmentVectorEnv",
]
