"""Gymnasium environments of qkf (SPEC §5), registered as ``qkf/...`` on import.

``qkf/TransferAlignment-v0`` wraps :class:`qkf.transfer_alignment.filter.TransferAlignmentKF`: the agent picks
the process-noise factor κ every decision period.
"""

from gymnasium.envs.registration import register, registry

from envs.transfer_alignment import TransferAlignmentEnv
from envs.vector import TransferAlignmentVectorEnv

ENV_ID = "qkf/TransferAlignment-v0"

if ENV_ID not in registry:
    register(
        id=ENV_ID,
        entry_point="envs.transfer_alignment:TransferAlignmentEnv",
        vector_entry_point="envs.vector:TransferAlignmentVectorEnv",
        max_episode_steps=360,
    )

__all__ = ["ENV_ID", "TransferAlignmentEnv", "TransferAlignmentVectorEnv"]
