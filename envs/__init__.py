"""Gymnasium environments of qkf, registered as ``qkf/...`` on import (docs/environment.md).

One package per environment, on the estimation problem it is built on, and what they share:

* :mod:`envs.transfer_alignment`: ``qkf/TransferAlignment-v0`` … ``-v3`` and
  ``qkf/TransferAlignmentTimed-v3``, the agent picks the transfer-alignment filter's
  process-noise factor κ every decision period; they differ only in the observation (the older
  ones stay as they were, for the policies trained on them; ``Timed-v3`` is v3 with the clock,
  an ablation); ``qkf/TransferAlignment-v4`` adds the filter's own moves (``controls=``:
  process noise per block, resets, the assumed ADS noise; residual corrections of a classical
  rule with ``base=``) and slow evidence. Single environment, batched Gymnasium vector
  environment, Stable-Baselines3 adapter.
* :mod:`envs.redundant_gyros`: ``qkf/RedundantGyroCalibration-v0``, the same question asked
  of the redundant-gyro calibration UKF (docs/redundant_gyros.md).
* :mod:`envs.common`: the κ action map, observation bounds, rendering, scenario checks and
  :data:`ENVIRONMENTS`, the registry of every id with its rewards, observation, scenario check
  and batched front ends: what ``qkf train`` looks an ``env:`` up in.

The episode length follows the config (the environments truncate themselves), so no
``max_episode_steps`` is registered. All accept ``render_mode=None`` or ``"rgb_array"`` (a
frame of the episode so far, drawn only by ``render()``), so Stable-Baselines3's
``make_vec_env`` and RL Zoo3 (``--gym-packages envs``, hyperparameters in
``agents/rl_zoo3/ppo.yml``) use them as they are. A worker process that has not imported this
package does not know the ids: name them ``"envs:qkf/TransferAlignment-v2"`` there (Gymnasium
imports the module before the lookup); docs/environment.md, "Stable-Baselines3 and RL Zoo3".
"""

from envs.common import ENVIRONMENTS, RENDER_MODES, ActionMap, Environment
from envs.transfer_alignment import (
    ENV_ID,
    ENV_ID_V1,
    ENV_ID_V2,
    ENV_ID_V3,
    ENV_ID_V3_TIMED,
    ENV_ID_V4,
    OBSERVATIONS,
    REWARDS,
    BatchedEpisodes,
    BatchedTransferAlignmentEnv,
    EpisodeDriver,
    Observation,
    PeriodOutcome,
    Reward,
    TransferAlignmentEnv,
)
from envs.transfer_alignment import ENV_OBSERVATIONS as TA_ENV_OBSERVATIONS

# isort: split
# registered after the transfer-alignment ids, so that listings (ENVIRONMENTS.names(), the
# "known:" of a message) name the main task first
from envs.redundant_gyros import GYRO_ENV_ID, GYRO_REWARDS, RedundantGyroCalibrationEnv

__all__ = [
    "ENVIRONMENTS",
    "ENV_ID",
    "ENV_ID_V1",
    "ENV_ID_V2",
    "ENV_ID_V3",
    "ENV_ID_V3_TIMED",
    "ENV_ID_V4",
    "GYRO_ENV_ID",
    "GYRO_REWARDS",
    "OBSERVATIONS",
    "RENDER_MODES",
    "REWARDS",
    "TA_ENV_OBSERVATIONS",
    "ActionMap",
    "BatchedEpisodes",
    "BatchedTransferAlignmentEnv",
    "Environment",
    "EpisodeDriver",
    "Observation",
    "PeriodOutcome",
    "RedundantGyroCalibrationEnv",
    "Reward",
    "TransferAlignmentEnv",
]
