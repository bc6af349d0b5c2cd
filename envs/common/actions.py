"""Actions → κ: the action map every qkf environment shares (docs/environment.md, "Actions").

Each environment offers the same two action types over its config's κ action set
(:class:`qkf.core.actions.ActionSet`): an index into the set (``discrete``) or one number in
[−1, 1] that is linear in ``log10 κ`` over the set's range (``continuous``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

ACTION_TYPES = ("discrete", "continuous")


class ActionMap:
    """Actions → κ, for both action types; invalid actions raise ``ValueError``."""

    def __init__(self, kappas: np.ndarray, action_type: str) -> None:
        if action_type not in ACTION_TYPES:
            raise ValueError(f"action_type must be 'discrete' or 'continuous', not {action_type!r}")
        self.kappas = kappas
        self.log_kappa = np.log10(kappas)
        self.action_type = action_type
        self.space: spaces.Space[Any] = (
            spaces.Discrete(kappas.size)
            if action_type == "discrete"
            else spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        )

    def __call__(self, action: Any) -> tuple[float, float]:
        """κ and its position in [0, 1] on the action scale."""
        if self.action_type == "discrete":
            if isinstance(action, int | np.integer) and not isinstance(action, bool):
                i = int(action)  # the common case, without the array checks below
            else:
                i = self._integral_index(action)
            if not 0 <= i < self.kappas.size:
                raise ValueError(f"action {i} outside 0..{self.kappas.size - 1}")
            return float(self.kappas[i]), i / (self.kappas.size - 1)
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.size != 1 or not np.isfinite(a[0]) or abs(a[0]) > 1.0 + 1e-6:
            raise ValueError(
                f"continuous action must be one finite value in [-1, 1], got {action!r}"
            )
        u = (float(np.clip(a[0], -1.0, 1.0)) + 1.0) / 2.0
        lo, hi = self.log_kappa[0], self.log_kappa[-1]
        return float(10.0 ** (lo + u * (hi - lo))), u

    def many(self, actions: Any) -> tuple[np.ndarray, np.ndarray]:
        """κ and position (N,) each of N actions; an integer array of discrete actions is
        mapped in one go (a batched environment's common case), anything else one by one."""
        a = np.asarray(actions)
        if self.action_type == "discrete" and a.ndim == 1 and np.issubdtype(a.dtype, np.integer):
            if a.size and (a.min() < 0 or a.max() >= self.kappas.size):
                bad = a[(a < 0) | (a >= self.kappas.size)][0]
                raise ValueError(f"action {int(bad)} outside 0..{self.kappas.size - 1}")
            return self.kappas[a].astype(float), a / (self.kappas.size - 1)
        mapped = [self(x) for x in actions]
        return np.array([m[0] for m in mapped]), np.array([m[1] for m in mapped])

    @staticmethod
    def _integral_index(action: Any) -> int:
        """A discrete action given as an array or a float: its integer value, or
        ``ValueError``."""
        a = np.asarray(action)
        v = a.reshape(-1)[0] if a.size == 1 else None
        integral = v is not None and (
            np.issubdtype(a.dtype, np.integer)
            or (np.issubdtype(a.dtype, np.floating) and np.isfinite(v) and float(v).is_integer())
        )
        if not integral:
            raise ValueError(f"discrete action must be an integer index, got {action!r}")
        return int(v)  # type: ignore[arg-type]
