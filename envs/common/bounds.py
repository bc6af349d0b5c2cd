"""Limits every qkf environment shares: the observation bound and the divergence reward."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

OBS_LIMIT = 100.0
"""Observations are clipped to ±this (NaN becomes 0, ±∞ becomes ±this)."""
DIVERGENCE_REWARD = -1e3
"""The reward of a step whose filter diverged, or whose reward is not finite."""


def finite_clipped(obs: np.ndarray) -> np.ndarray:
    """NaN → 0, ±∞ → ±OBS_LIMIT, clipped to ±OBS_LIMIT, float32."""
    # the same as nan_to_num(nan=0, ±inf=±OBS_LIMIT) then clip, in three ufunc calls: the
    # single environment builds one observation per step, where call overhead is the cost
    obs = np.where(np.isnan(obs), 0.0, obs)
    return np.minimum(np.maximum(obs, -OBS_LIMIT), OBS_LIMIT).astype(np.float32)


def observation_box(size: int) -> spaces.Box:
    """The observation space of ``size`` entries: ``Box(−OBS_LIMIT, OBS_LIMIT, (size,))``."""
    return spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(size,), dtype=np.float32)
