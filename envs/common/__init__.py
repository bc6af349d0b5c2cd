"""What every qkf environment shares: the κ action map, observation bounds and the divergence
reward, rendering, scenario checks and the environment registry."""

from envs.common.actions import ACTION_TYPES, ActionMap
from envs.common.bounds import DIVERGENCE_REWARD, OBS_LIMIT, finite_clipped, observation_box
from envs.common.registry import ENVIRONMENTS, ActingPolicy, Environment, register_environment
from envs.common.render import (
    FRAME_HEIGHT_PX,
    FRAME_WIDTH_PX,
    RENDER_FPS,
    RENDER_MODES,
    EpisodeTrace,
    check_render_mode,
)
from envs.common.scenario import message_lines, scenario_problems

__all__ = [
    "ACTION_TYPES",
    "DIVERGENCE_REWARD",
    "ENVIRONMENTS",
    "FRAME_HEIGHT_PX",
    "FRAME_WIDTH_PX",
    "OBS_LIMIT",
    "RENDER_FPS",
    "RENDER_MODES",
    "ActingPolicy",
    "ActionMap",
    "Environment",
    "EpisodeTrace",
    "check_render_mode",
    "finite_clipped",
    "message_lines",
    "observation_box",
    "register_environment",
    "scenario_problems",
]
