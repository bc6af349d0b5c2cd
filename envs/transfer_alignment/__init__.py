"""The transfer-alignment environments ``qkf/TransferAlignment-v0`` … ``-v3`` and the ablation
``qkf/TransferAlignmentTimed-v3`` (docs/environment.md): the agent picks the calibration
process-noise factor κ of the transfer-alignment filter (:mod:`qkf.transfer_alignment`) every
decision period.

The ids up to v3 differ only in the observation (:mod:`.observations`: ``v0`` … ``v3``,
``v3-time``); the older ones stay as they were, for the policies trained on them. ``-v4`` adds
the filter's own moves as actions (``controls=``, :mod:`.controls`: process noise per block,
calibration resets, the assumed ADS noise, residual corrections of a classical rule) and slow
evidence to the observation. The package holds every front
end of the task over one set of batched episodes (:mod:`.episodes`): the single environment
(:mod:`.env`), the batched Gymnasium vector environment (:mod:`.vector`, what ``gym.make_vec``
returns) and its Stable-Baselines3 adapter (:mod:`.sb3`, imported only when used: it loads
torch), with the rewards (:mod:`.rewards`). Importing it registers the ids, with Gymnasium and in
:data:`envs.ENVIRONMENTS`.
"""

from collections.abc import Sequence

from envs.common.registry import Environment, register_environment
from envs.common.scenario import scenario_problems
from envs.transfer_alignment.env import TransferAlignmentEnv
from envs.transfer_alignment.episodes import (
    DEFAULT_PERIOD_S,
    BatchedEpisodes,
    EpisodeDriver,
    StepOutput,
)
from envs.transfer_alignment.observations import OBSERVATIONS, Observation, PeriodView
from envs.transfer_alignment.rewards import REWARDS, PeriodOutcome, Reward
from envs.transfer_alignment.vector import BatchedTransferAlignmentEnv
from qkf.transfer_alignment.config import load_scenario

ENV_ID = "qkf/TransferAlignment-v0"
ENV_ID_V1 = "qkf/TransferAlignment-v1"
ENV_ID_V2 = "qkf/TransferAlignment-v2"
ENV_ID_V3 = "qkf/TransferAlignment-v3"
ENV_ID_V3_TIMED = "qkf/TransferAlignmentTimed-v3"
ENV_ID_V4 = "qkf/TransferAlignment-v4"
ENV_OBSERVATIONS = {
    ENV_ID: "v0",
    ENV_ID_V1: "v1",
    ENV_ID_V2: "v2",
    ENV_ID_V3: "v3",
    ENV_ID_V3_TIMED: "v3-time",
    ENV_ID_V4: "v4",
}
"""The transfer-alignment environment ids and the observation each one uses."""


def check_scenario(scenario: str, overrides: Sequence[str]) -> list[str]:
    """Problems of a transfer-alignment ``scenario`` (preset name or path) with its
    ``overrides``, one ``scenario: …`` / ``overrides: …`` line each (empty: it makes episodes)."""
    return scenario_problems(load_scenario, scenario, overrides)


_DESCRIPTIONS = {
    "v0": "transfer alignment, the original 9-entry observation (kept for its policies)",
    "v1": "transfer alignment, the 12-entry order-one observation (kept for its policies)",
    "v2": "transfer alignment, v1 and the age of the current change (kept for its policies)",
    "v3": "transfer alignment, evidence without the clock: covariance levels, NIS per block, "
    "CUSUM, alarms, rate excitation (current)",
    "v3-time": "transfer alignment, v3 and the elapsed fraction (the ablation of the clock)",
    "v4": "transfer alignment with the filter's own moves (controls=: kappa, blocks, reset, "
    "r_scale, joined with +; base= for residual controls) and slow evidence (current)",
}
V4_OPTIONS = ("controls", "base", "expert")
"""The keywords of v4 a training config's ``env_kwargs`` may set."""

for _id, _obs in ENV_OBSERVATIONS.items():
    register_environment(
        Environment(
            id=_id,
            entry_point="envs.transfer_alignment.env:TransferAlignmentEnv",
            problem="transfer_alignment",
            rewards=REWARDS,
            observation_size=OBSERVATIONS[_obs].size,
            check_scenario=check_scenario,
            observation=_obs,
            vector_entry_point="envs.transfer_alignment.vector:BatchedTransferAlignmentEnv",
            sb3_vec_env="envs.transfer_alignment.sb3:BatchedTransferAlignmentSB3Env",
            policy_runner="envs.transfer_alignment.judging:run_policy",
            policy_check="envs.transfer_alignment.judging:check_policy",
            description=_DESCRIPTIONS[_obs],
            defaults=(("controls", "kappa"),) if _obs == "v4" else (),
            options=V4_OPTIONS if _obs == "v4" else (),
            datasets="envs.transfer_alignment.datasets:DATASETS" if _obs == "v4" else None,
        )
    )

__all__ = [
    "DEFAULT_PERIOD_S",
    "ENV_ID",
    "ENV_ID_V1",
    "ENV_ID_V2",
    "ENV_ID_V3",
    "ENV_ID_V3_TIMED",
    "ENV_ID_V4",
    "ENV_OBSERVATIONS",
    "OBSERVATIONS",
    "REWARDS",
    "BatchedEpisodes",
    "BatchedTransferAlignmentEnv",
    "EpisodeDriver",
    "Observation",
    "PeriodOutcome",
    "PeriodView",
    "Reward",
    "StepOutput",
    "TransferAlignmentEnv",
    "check_scenario",
]
