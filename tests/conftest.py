from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from qkf.transfer_alignment.config import Config, load_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


@pytest.fixture
def paper() -> Config:
    return load_config(CONFIGS / "paper.yaml")


def cfg_with(*sets: str, base: str = "paper.yaml") -> Config:
    """A preset with ``--set`` style overrides."""
    return load_config(CONFIGS / base, list(sets))


def align_quat_sign(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Flip quaternions (last axis 4) onto the hemisphere of ``ref`` (q and −q are one rotation)."""
    s = np.sign(np.sum(q * ref, axis=-1, keepdims=True))
    return q * np.where(s == 0, 1.0, s)
