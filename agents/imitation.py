"""Imitation learning for Stable-Baselines3 policies: behavioural cloning and DAgger.

A short loop of our own (the ``imitation`` library does not install beside SB3 2.9 and
gymnasium 1.4); ``qkf train`` runs it before reinforcement learning when a training config has
``imitation:`` (:class:`agents.config.ImitationConfig`). This module imports torch; it is
imported only where it is used.

**Behavioural cloning** (:func:`behaviour_clone`). Given expert pairs
:math:`\\mathcal D = \\{(o_i, a_i)\\}_{i=1}^M`, maximise their log-likelihood under the
policy :math:`\\pi_\\theta`,

.. math::

    \\hat\\theta = \\arg\\min_\\theta L(\\theta), \\qquad
    L(\\theta) = -\\frac{1}{M} \\sum_{i=1}^{M} \\log \\pi_\\theta(a_i \\mid o_i),

by Adam on shuffled minibatches. :math:`\\log \\pi_\\theta(a \\mid o)` is the policy's own
(``ActorCriticPolicy.evaluate_actions``): a categorical for ``Discrete``, a sum of independent
categoricals for ``MultiDiscrete``, a diagonal Gaussian for ``Box`` (whose σ the cloning
shrinks as the mean fits). Only the actor part of the loss is used; the value head is left as
it is (its gradient is zero: PPO's later updates fit it from the returns).

**DAgger** (:func:`dagger`; Ross, Gordon & Bagnell 2011, *A reduction of imitation learning and
structured prediction to no-regret online learning*). Cloning alone learns on the expert's
state distribution :math:`d_{\\pi^*}` and errs where its own mistakes lead; DAgger trains on the
states the learner visits. Round :math:`r = 0, 1, \\dots, R-1` drives the environment with the
mixture

.. math::

    \\pi_r = \\beta_r\\, \\pi^* + (1 - \\beta_r)\\, \\hat\\pi_r, \\qquad
    \\beta_r = \\beta_0\\, \\gamma^r,

(per environment and step: the expert's action with probability :math:`\\beta_r`, else the
learner's deterministic action), labels *every* visited observation with the expert's action
:math:`\\pi^*(s)`, adds them to the aggregate :math:`\\mathcal D \\leftarrow \\mathcal D \\cup
\\mathcal D_r` and clones :math:`\\hat\\pi_{r+1}` on all of :math:`\\mathcal D`. The expert may
see the whole environment state :math:`s`, not only the observation :math:`o` (here: the
truth of the simulation), which is what makes it an expert the policy can only approach.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

Expert = Callable[[], np.ndarray]
"""The expert: its actions ``(n_envs, ...)`` for the vectorised environment's current state."""

BOX_AGREEMENT = 0.05
"""Box actions agree when every component is within this share of the action space's width
(an absolute tolerance where the space is unbounded)."""


@dataclass(frozen=True)
class DaggerRound:
    """One DAgger round: its mixture weight β, the observations it added, the cloning loss
    (mean −log π(a|o) over the aggregate in the last epoch) and the share of the round's
    visited states where the learner's deterministic action was the expert's (measured
    before this round's cloning: round 0 judges the policy as it came in)."""

    round: int
    beta: float
    samples: int
    loss: float
    agreement: float


def _check_policy(model: Any) -> None:
    """``ValueError`` unless ``model`` has a non-recurrent policy with ``evaluate_actions``."""
    policy = getattr(model, "policy", None)
    name = type(model).__name__
    if policy is None:
        raise ValueError(f"imitation needs a Stable-Baselines3 model with a policy, not {name}")
    evaluate = getattr(policy, "evaluate_actions", None)
    if evaluate is None:
        raise ValueError(
            f"imitation needs a policy with evaluate_actions (an actor-critic: PPO, A2C); "
            f"{name}'s {type(policy).__name__} has none"
        )
    if "lstm_states" in inspect.signature(evaluate).parameters:
        raise ValueError(
            f"imitation does not support recurrent policies ({name}'s "
            f"{type(policy).__name__} carries an LSTM state between steps)"
        )
    if isinstance(policy.observation_space, spaces.Dict):
        raise ValueError("imitation supports array observations, not a Dict observation space")


def _action_array(actions: Any, space: spaces.Space[Any], n: int) -> np.ndarray:
    """``actions`` as the space wants them for ``n`` samples: ``(n,)`` for Discrete,
    ``(n, k)`` for MultiDiscrete, ``(n, *shape)`` for Box."""
    a = np.asarray(actions)
    if isinstance(space, spaces.Discrete):
        return a.reshape(n).astype(np.int64)
    if isinstance(space, spaces.MultiDiscrete | spaces.MultiBinary):
        return a.reshape((n, *space.shape)).astype(np.int64)
    if isinstance(space, spaces.Box):
        return a.reshape((n, *space.shape)).astype(np.float32)
    raise ValueError(f"imitation does not support {type(space).__name__} action spaces")


def behaviour_clone(
    model: Any,
    observations: np.ndarray,
    actions: np.ndarray,
    *,
    epochs: int,
    batch_size: int,
    learning_rate: float,
    seed: int,
) -> list[float]:
    """Fit ``model.policy`` to expert pairs by maximum likelihood; the mean loss per epoch.

    Minimises :math:`L(\\theta) = -\\frac1M \\sum_i \\log \\pi_\\theta(a_i \\mid o_i)` with a
    fresh Adam (``learning_rate``) over ``model.policy.parameters()``, ``epochs`` passes over
    the data in minibatches of ``batch_size`` (the last one smaller), shuffled each epoch by a
    numpy ``Generator`` seeded with ``seed``; ``torch.manual_seed(seed)`` too, so two calls with
    the same model and inputs give bit-identical weights. ``observations``: ``(M, *obs_shape)``;
    ``actions``: ``(M,)`` integers for ``Discrete``, ``(M, k)`` for ``MultiDiscrete``,
    ``(M, *shape)`` for ``Box``. The model's own optimizer (PPO's) is not touched.

    ``ValueError`` for a model whose policy has no ``evaluate_actions`` (off-policy algorithms:
    DQN, SAC), a recurrent policy (sb3-contrib's ``RecurrentPPO``) or mismatched inputs.
    """
    _check_policy(model)
    if epochs < 1 or batch_size < 1 or not learning_rate > 0:
        raise ValueError("epochs and batch_size must be ≥ 1 and learning_rate > 0")
    policy = model.policy
    obs = np.asarray(observations, dtype=np.float32)
    m = len(obs)
    if m == 0:
        raise ValueError("behaviour_clone: no observations")
    acts = _action_array(actions, policy.action_space, m)
    obs = obs.reshape((m, *policy.observation_space.shape))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    device = policy.device
    obs_t = torch.as_tensor(obs, device=device)
    act_t = torch.as_tensor(acts, device=device)
    optimizer = torch.optim.Adam(policy.parameters(), lr=learning_rate)
    policy.set_training_mode(True)
    losses: list[float] = []
    try:
        for _ in range(epochs):
            order = torch.as_tensor(rng.permutation(m), device=device)
            total = 0.0
            for start in range(0, m, batch_size):
                idx = order[start : start + batch_size]
                _, log_prob, _ = policy.evaluate_actions(obs_t[idx], act_t[idx])
                loss = -log_prob.mean()
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                total += float(loss.detach()) * len(idx)
            losses.append(total / m)
    finally:
        policy.set_training_mode(False)
    return losses


def _agree(learner: np.ndarray, expert: np.ndarray, space: spaces.Space[Any]) -> np.ndarray:
    """Per sample: whether the learner's action is the expert's (Box: within
    :data:`BOX_AGREEMENT` of the space's width in every component)."""
    n = len(learner)
    if isinstance(space, spaces.Box):
        width = np.asarray(space.high, dtype=float) - np.asarray(space.low, dtype=float)
        tol = np.where(np.isfinite(width), BOX_AGREEMENT * width, BOX_AGREEMENT)
        close = np.abs(learner.astype(float) - expert.astype(float)) <= tol
        return close.reshape(n, -1).all(axis=1)
    return (learner == expert).reshape(n, -1).all(axis=1)


def dagger(
    model: Any,
    venv: VecEnv,
    expert: Expert,
    *,
    rounds: int,
    steps_per_round: int,
    beta0: float = 1.0,
    beta_decay: float = 0.5,
    epochs: int,
    batch_size: int,
    learning_rate: float,
    seed: int,
) -> list[DaggerRound]:
    """DAgger: ``rounds`` rounds of collecting with the mixture policy, then cloning on all
    data so far (:func:`behaviour_clone`); the rounds' records.

    ``venv`` is reset once (``venv.reset()``), then driven for ``steps_per_round`` vector
    steps per round (each a step of all ``venv.num_envs`` environments, so a round adds
    ``steps_per_round × num_envs`` samples), episodes restarting by the VecEnv's own
    autoreset. In round ``r``, per environment and step, the action is the expert's with
    probability :math:`\\beta_r = \\beta_0 \\gamma^r` (``beta_decay`` = γ), else the learner's
    ``model.predict(obs, deterministic=True)``; every visited observation is labelled with the
    expert's action. ``expert()`` returns the expert's actions for the environments' current
    state; it is called after the reset and after every step, before the next action is chosen.
    The mixture draws come from a numpy ``Generator`` seeded with ``seed``; round ``r`` clones
    with seed ``seed + r``. ``model`` is trained in place.
    """
    _check_policy(model)
    if rounds < 1 or steps_per_round < 1:
        raise ValueError("rounds and steps_per_round must be ≥ 1")
    if not (0.0 <= beta0 <= 1.0 and 0.0 <= beta_decay <= 1.0):
        raise ValueError("beta0 and beta_decay must lie in [0, 1]")
    space = venv.action_space
    n = venv.num_envs
    rng = np.random.default_rng(seed)
    all_obs: list[np.ndarray] = []
    all_act: list[np.ndarray] = []
    records: list[DaggerRound] = []
    obs = venv.reset()
    if isinstance(obs, dict):
        raise ValueError("imitation supports array observations, not dict observations")
    target = _action_array(expert(), space, n)
    for r in range(rounds):
        beta = beta0 * beta_decay**r
        agreed = 0
        for _ in range(steps_per_round):
            learner, _ = model.predict(obs, deterministic=True)
            learner = _action_array(learner, space, n)
            agreed += int(_agree(learner, target, space).sum())
            all_obs.append(np.array(obs, dtype=np.float32, copy=True))
            all_act.append(target.copy())
            use_expert = rng.random(n) < beta
            mask = use_expert.reshape((n,) + (1,) * (target.ndim - 1))
            action = np.where(mask, target, learner)
            obs, _, _, _ = venv.step(action)
            target = _action_array(expert(), space, n)
        losses = behaviour_clone(
            model,
            np.concatenate(all_obs),
            np.concatenate(all_act),
            epochs=epochs,
            batch_size=batch_size,
            learning_rate=learning_rate,
            seed=seed + r,
        )
        samples = steps_per_round * n
        records.append(DaggerRound(r, beta, samples, losses[-1], agreed / samples))
    return records


def find_expert(venv: VecEnv) -> Expert:
    """The ``expert_actions`` method of the first environment with one, walking SB3
    ``VecEnvWrapper`` chains (``.venv``) from ``venv`` down; ``ValueError`` naming the
    innermost environment's class if none has one."""
    env: Any = venv
    while isinstance(env, VecEnvWrapper):
        # the wrapper's class, not getattr(env): SB3 wrappers forward unknown attributes
        if callable(getattr(type(env), "expert_actions", None)):
            break
        env = env.venv
    method = getattr(env, "expert_actions", None)
    if callable(method):
        bound: Expert = method
        return bound
    raise ValueError(
        f"imitation needs an expert, and {type(env).__name__} has no expert_actions() "
        "(does the environment take expert=, and is it set in env_kwargs?)"
    )
