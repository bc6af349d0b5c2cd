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
    obs = np.nan_to_num(obs, nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
    return np.clip(obs, -OBS_LIMIT, OBS_LIMIT).astype(np.float32)


def observation_box(size: int) -> spaces.Box:
    """The observation space of ``size`` entries: ``Box(−OBS_LIMIT, OBS_LIMIT, (size,))``."""
    return spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(size,), dtype=np.float32)
