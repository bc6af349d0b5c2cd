"""The single environment and the batched vector environment give the same trajectories for the
same seeds and actions (the single one runs the kernel's serial path, B = 1; the batched one its
parallel path; docs/performance.md)."""

from __future__ import annotations

import numpy as np
import pytest

from envs import BatchedTransferAlignmentEnv, TransferAlignmentEnv
from qkf.core.jit import SERIAL_BELOW

SETS = ["scenario.duration_s=200"]


@pytest.mark.parametrize("observation", ["v0", "v3"])
@pytest.mark.parametrize("reward", ["likelihood", "relative_state_gain"])
def test_single_and_batched_trajectories_agree(observation: str, reward: str) -> None:
    n = SERIAL_BELOW + 2  # the batched env takes the parallel path
    vec = BatchedTransferAlignmentEnv(n, overrides=SETS, observation=observation, reward=reward)
    singles = [
        TransferAlignmentEnv(overrides=SETS, observation=observation, reward=reward)
        for _ in range(n)
    ]
    obs_v, _ = vec.reset(seed=40)
    obs_s = np.stack([env.reset(seed=40 + i)[0] for i, env in enumerate(singles)])
    np.testing.assert_array_equal(obs_v, obs_s)
    rng = np.random.default_rng(3)
    steps = singles[0].episode_steps
    for _ in range(steps):
        actions = rng.integers(0, 11, n)
        obs_v, rew_v, term_v, trunc_v, _ = vec.step(actions)
        outs = [env.step(int(a)) for env, a in zip(singles, actions, strict=True)]
        np.testing.assert_array_equal(obs_v, np.stack([o[0] for o in outs]))
        np.testing.assert_array_equal(rew_v, np.array([o[1] for o in outs]))
        assert list(trunc_v) == [o[3] for o in outs] and list(term_v) == [o[2] for o in outs]
    assert all(o[3] for o in outs)  # the episodes ran to their end
    # the next step restarts every episode together (one batch of reference filters for all,
    # reset_envs); each single environment restarts on its own: the same new episodes
    obs_v, rew_v, _, _, _ = vec.step(rng.integers(0, 11, n))
    np.testing.assert_array_equal(obs_v, np.stack([env.reset()[0] for env in singles]))
    np.testing.assert_array_equal(rew_v, np.zeros(n))
    for _ in range(3):
        actions = rng.integers(0, 11, n)
        obs_v, rew_v, _, _, _ = vec.step(actions)
        outs = [env.step(int(a)) for env, a in zip(singles, actions, strict=True)]
        np.testing.assert_array_equal(obs_v, np.stack([o[0] for o in outs]))
        np.testing.assert_array_equal(rew_v, np.array([o[1] for o in outs]))
