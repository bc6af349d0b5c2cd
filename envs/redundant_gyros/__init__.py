"""The redundant-gyro environments ``qkf/RedundantGyroCalibration-v0`` and ``-v1``
(docs/redundant_gyros.md, "Environment"): the agent picks the process-noise factor κ of the UKF
that calibrates one gyro of a redundant skewed unit (:mod:`qkf.redundant_gyros`) every decision
period. v1 runs on ``five_gyros_onset_drift`` by default (an onset drawn per episode, drifting
coefficients) and its observation has no elapsed-time entry; v0 stays as it was.

:mod:`.env` is the single environment, :mod:`.rewards` its reward registry. It has no batched
vector environment: ``gym.make_vec`` and ``qkf train`` run one environment per episode.
Importing it registers the id, with Gymnasium and in :data:`envs.ENVIRONMENTS`.
"""

from collections.abc import Sequence

from envs.common.registry import Environment, register_environment
from envs.common.scenario import scenario_problems
from envs.redundant_gyros.env import OBS_SIZE, OBS_SIZES, RedundantGyroCalibrationEnv
from envs.redundant_gyros.rewards import GYRO_REWARDS, GyroPeriod, GyroReward
from qkf.redundant_gyros.config import GyrosConfig, load_config
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import fault_target
from qkf.redundant_gyros.scenario import epochs

GYRO_ENV_ID = "qkf/RedundantGyroCalibration-v0"
GYRO_ENV_ID_V1 = "qkf/RedundantGyroCalibration-v1"


def _has_a_gyro_to_calibrate(cfg: GyrosConfig) -> None:
    """``ValueError`` unless the scenario names a gyro to calibrate (``calibration.gyro`` or a
    fault): an episode is that gyro's calibration."""
    fault_target(cfg, build_unit(cfg), epochs(cfg.scenario.duration_s, cfg.scenario.dt_s))


def check_scenario(scenario: str, overrides: Sequence[str]) -> list[str]:
    """Problems of a redundant-gyro ``scenario`` (preset name or path) with its ``overrides``,
    one ``scenario: …`` / ``overrides: …`` line each (empty: it makes episodes)."""
    return scenario_problems(load_config, scenario, overrides, _has_a_gyro_to_calibrate)


register_environment(
    Environment(
        id=GYRO_ENV_ID,
        entry_point="envs.redundant_gyros.env:RedundantGyroCalibrationEnv",
        problem="redundant_gyros",
        rewards=GYRO_REWARDS,
        observation_size=OBS_SIZE,
        check_scenario=check_scenario,
        description="redundant skewed gyros: κ of the calibration UKF of one gyro",
    )
)
register_environment(
    Environment(
        id=GYRO_ENV_ID_V1,
        entry_point="envs.redundant_gyros.env:RedundantGyroCalibrationEnv",
        problem="redundant_gyros",
        rewards=GYRO_REWARDS,
        observation_size=OBS_SIZES["v1"],
        check_scenario=check_scenario,
        observation="v1",
        description=(
            "redundant skewed gyros, unknown fault onset and drifting coefficients; "
            "no clock in the observation"
        ),
    )
)

__all__ = [
    "GYRO_ENV_ID",
    "GYRO_ENV_ID_V1",
    "GYRO_REWARDS",
    "OBS_SIZE",
    "OBS_SIZES",
    "GyroPeriod",
    "GyroReward",
    "RedundantGyroCalibrationEnv",
    "check_scenario",
]
