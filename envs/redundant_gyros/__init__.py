"""The redundant-gyro environments ``qkf/RedundantGyroCalibration-v0`` … ``-v4``
(docs/redundant_gyros.md, "Environment"): the agent picks the process-noise factor κ of the UKF
that calibrates one gyro of a redundant skewed unit (:mod:`qkf.redundant_gyros`) every decision
period. v1 runs on ``five_gyros_onset_drift`` by default (an onset drawn per episode, drifting
coefficients) and its observation has no elapsed-time entry; v2 also leaves out the likelihood
gain over a κ = 1 copy (so no copy runs) and rewards with ``oracle`` by default; v3 adds the
lag-1 correlation of the normalised innovations to v2 and runs on ``gyro_noise_levels`` by
default; v4 adds to v3 the variational-Bayes estimate of the white noise's scale (what the
``vb-noise`` baseline reads); v0 stays as it was.

:mod:`.episodes` steps N episodes through the compiled UKF; :mod:`.env` is the single
environment (one episode), :mod:`.vector` the batched Gymnasium ``VectorEnv`` (what
``gym.make_vec`` returns), :mod:`.sb3` its Stable-Baselines3 twin (what ``qkf train`` uses);
:mod:`.observations` and :mod:`.rewards` are the registries. Importing it registers the ids,
with Gymnasium and in :data:`envs.ENVIRONMENTS`.
"""

from collections.abc import Sequence

from envs.common.registry import Environment, register_environment
from envs.common.scenario import scenario_problems
from envs.redundant_gyros.env import OBS_SIZE, OBS_SIZES, RedundantGyroCalibrationEnv
from envs.redundant_gyros.rewards import GYRO_REWARDS, GyroPeriod, GyroReward
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import fault_target
from qkf.redundant_gyros.scenario import epochs

GYRO_ENV_ID = "qkf/RedundantGyroCalibration-v0"
GYRO_ENV_ID_V1 = "qkf/RedundantGyroCalibration-v1"
GYRO_ENV_ID_V2 = "qkf/RedundantGyroCalibration-v2"
GYRO_ENV_ID_V3 = "qkf/RedundantGyroCalibration-v3"
GYRO_ENV_ID_V4 = "qkf/RedundantGyroCalibration-v4"
VECTOR_ENTRY_POINT = "envs.redundant_gyros.vector:BatchedGyroCalibrationEnv"
SB3_VEC_ENV = "envs.redundant_gyros.sb3:BatchedGyroSB3Env"


def _has_a_gyro_to_calibrate(cfg: GyrosConfig) -> None:
    """``ValueError`` unless the scenario names a gyro to calibrate (``calibration.gyro`` or a
    fault): an episode is that gyro's calibration."""
    fault_target(cfg, build_unit(cfg), epochs(cfg.scenario.duration_s, cfg.scenario.dt_s))


def check_scenario(scenario: str, overrides: Sequence[str]) -> list[str]:
    """Problems of a redundant-gyro ``scenario`` (preset name or path) with its ``overrides``,
    one ``scenario: …`` / ``overrides: …`` line each (empty: it makes episodes)."""
    return scenario_problems(load_config, scenario, overrides, _has_a_gyro_to_calibrate)


VERSIONS = {
    GYRO_ENV_ID: ("v0", "redundant skewed gyros: κ of the calibration UKF of one gyro"),
    GYRO_ENV_ID_V1: (
        "v1",
        "redundant skewed gyros, unknown fault onset and drifting coefficients; no clock in "
        "the observation",
    ),
    GYRO_ENV_ID_V2: (
        "v2",
        "redundant skewed gyros as v1, without the κ = 1 copy's likelihood gain in the "
        "observation; oracle reward by default",
    ),
    GYRO_ENV_ID_V3: (
        "v3",
        "redundant skewed gyros, noise levels unknown to the filter (gyro_noise_levels): v2's "
        "observation with the innovations' lag-1 correlation",
    ),
    GYRO_ENV_ID_V4: (
        "v4",
        "redundant skewed gyros, noise levels unknown to the filter (gyro_noise_levels): v3's "
        "observation with the VB estimate of the white noise's scale (what vb-noise reads)",
    ),
}
"""Each id's observation version and description (one environment class, one per version)."""
for _env_id, (_observation, _description) in VERSIONS.items():
    register_environment(
        Environment(
            id=_env_id,
            entry_point="envs.redundant_gyros.env:RedundantGyroCalibrationEnv",
            problem="redundant_gyros",
            rewards=GYRO_REWARDS,
            observation_size=OBS_SIZES[_observation],
            check_scenario=check_scenario,
            observation=_observation,
            vector_entry_point=VECTOR_ENTRY_POINT,
            sb3_vec_env=SB3_VEC_ENV,
            policy_runner="envs.redundant_gyros.judging:run_policy",
            policy_check="envs.redundant_gyros.judging:check_policy",
            description=_description,
        )
    )

__all__ = [
    "GYRO_ENV_ID",
    "GYRO_ENV_ID_V1",
    "GYRO_ENV_ID_V2",
    "GYRO_ENV_ID_V3",
    "GYRO_ENV_ID_V4",
    "GYRO_REWARDS",
    "OBS_SIZE",
    "OBS_SIZES",
    "GyroPeriod",
    "GyroReward",
    "RedundantGyroCalibrationEnv",
    "check_scenario",
]
