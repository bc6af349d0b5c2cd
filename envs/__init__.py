"""Gymnasium environments of qkf, registered as ``qkf/...`` on import (docs/environment.md).

``qkf/TransferAlignment-v0`` wraps the transfer-alignment filter: the agent picks the
process-noise factor κ every decision period. The episode length follows the config (the
environment truncates itself), so no ``max_episode_steps`` is registered.
``qkf/TransferAlignment-v1`` is the same task with the order-one observation ``v1``
(:mod:`envs.observations`), ``qkf/TransferAlignment-v2`` adds the age of the current change to
it; v0 and v1 stay as they were, for the policies trained on them.
``qkf/RedundantGyroCalibration-v0`` asks the same of the redundant-gyro calibration UKF
(docs/redundant_gyros.md).

All accept ``render_mode=None`` or ``"rgb_array"`` (a frame of the episode so far, drawn only
by ``render()``), so Stable-Baselines3's ``make_vec_env`` and RL Zoo3 (``--gym-packages envs``,
hyperparameters in ``agents/rl_zoo3/ppo.yml``) use them as they are. A worker process that has
not imported this package does not know the ids: name them ``"envs:qkf/TransferAlignment-v2"``
there (Gymnasium imports the module before the lookup); docs/environment.md, "Stable-Baselines3
and RL Zoo3".
"""

from gymnasium.envs.registration import register, registry

from envs.episodes import ActionMap, BatchedEpisodes, EpisodeDriver
from envs.observations import OBSERVATIONS, Observation
from envs.redundant_gyro import GYRO_REWARDS, RedundantGyroCalibrationEnv
from envs.rewards import REWARDS, PeriodOutcome, Reward
from envs.transfer_alignment import RENDER_MODES, TransferAlignmentEnv
from envs.vector import TransferAlignmentVectorEnv

ENV_ID = "qkf/TransferAlignment-v0"
ENV_ID_V1 = "qkf/TransferAlignment-v1"
ENV_ID_V2 = "qkf/TransferAlignment-v2"
TA_ENV_OBSERVATIONS = {ENV_ID: "v0", ENV_ID_V1: "v1", ENV_ID_V2: "v2"}
"""The transfer-alignment environment ids and the observation each one uses."""

for _id, _obs in TA_ENV_OBSERVATIONS.items():
    if _id not in registry:
        register(
            id=_id,
            entry_point="envs.transfer_alignment:TransferAlignmentEnv",
            vector_entry_point="envs.vector:TransferAlignmentVectorEnv",
            max_episode_steps=None,
            kwargs={"observation": _obs},
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
    "ENV_ID_V1",
    "ENV_ID_V2",
    "GYRO_ENV_ID",
    "GYRO_REWARDS",
    "OBSERVATIONS",
    "RENDER_MODES",
    "REWARDS",
    "TA_ENV_OBSERVATIONS",
    "ActionMap",
    "BatchedEpisodes",
    "EpisodeDriver",
    "Observation",
    "PeriodOutcome",
    "RedundantGyroCalibrationEnv",
    "Reward",
    "TransferAlignmentEnv",
    "TransferAlignmentVectorEnv",
]
