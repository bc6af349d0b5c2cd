"""Gymnasium environments of qkf, registered as ``qkf/...`` on import (docs/environment.md).

``qkf/TransferAlignment-v0`` wraps the transfer-alignment filter: the agent picks the
process-noise factor κ every decision period. The episode length follows the config (the
environment truncates itself), so no ``max_episode_steps`` is registered.
"""

from gymnasium.envs.registration import register, registry

from envs.episodes import ActionMap, BatchedEpisodes, EpisodeDriver
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

__all__ = [
    "ENV_ID",
    "REWARDS",
    "ActionMap",
    "BatchedEpisodes",
    "EpisodeDriver",
    "PeriodOutcome",
    "Reward",
    "TransferAlignmentEnv",
    "TransferAlignmentVectorEnv",
]
