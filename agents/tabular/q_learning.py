r"""Tabular Q-learning agent: the QKF's learner as an episodic agent over the environment.

The observation is discretised on chosen dimensions (``bins``: observation index → bin edges);
the state is the tuple of bin indices, flattened. Learning is one-step Q-learning with an
ε-greedy behaviour policy whose ε decays exponentially per episode::

    Q(s, a) += α (r + γ (1 − terminated) max_a' Q(s', a') − Q(s, a))

``act(obs, deterministic=True)`` is greedy, ties broken towards the lowest action. Everything
random comes from the agent's own generator (``seed``), so training is reproducible. The agent
counts what it has learned from: ``episodes`` ended, ``steps`` (transitions, i.e. environment
steps) and ``visits`` per state; all three are saved with it.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.io import atomic_write_bytes

DEFAULT_BINS: dict[int, list[float]] = {
    # obs 2: mean log10(σ/σ₀) of the calibration block — how converged the calibration is
    2: [-3.0, -2.5, -2.0, -1.5, -1.0],
    # obs 5: likelihood gain against the nominal filter, per epoch and row
    5: [-1e-4, -1e-6, 1e-6, 1e-4],
    # obs 7: |ω̂| in deg/s — manoeuvring or not
    7: [0.2],
    # obs 8: the κ in use (scaled index)
    8: [(i + 0.5) / 10 for i in range(10)],
}


@dataclass
class TabularQAgent:
    n_actions: int
    bins: dict[int, list[float]] = field(default_factory=lambda: dict(DEFAULT_BINS))
    alpha: float = 0.1
    gamma: float = 0.9
    epsilon_start: float = 0.3
    epsilon_end: float = 0.02
    epsilon_decay_episodes: float = 30.0
    seed: int = 0
    table: np.ndarray = field(init=False)
    episodes: int = field(init=False, default=0)
    steps: int = field(init=False, default=0)
    visits: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        if self.n_actions < 2:
            raise ValueError("n_actions: must be at least 2")
        self._check_numbers()
        self.bins = _check_bins(self.bins)
        self._dims = sorted(self.bins)
        self._sizes = [len(self.bins[d]) + 1 for d in self._dims]
        self.table = np.zeros((int(np.prod(self._sizes)), self.n_actions))
        self.visits = np.zeros(self.table.shape[0], dtype=np.int64)
        self.rng = np.random.default_rng(self.seed)

    def _check_numbers(self) -> None:
        """``ValueError`` naming the field (``alpha: …``) for a setting out of its range."""
        ranges: dict[str, tuple[float, float, bool]] = {  # name: (low, high, low included)
            "alpha": (0.0, 1.0, False),
            "gamma": (0.0, 1.0, True),
            "epsilon_start": (0.0, 1.0, True),
            "epsilon_end": (0.0, 1.0, True),
            "epsilon_decay_episodes": (0.0, math.inf, False),
        }
        for name, (low, high, closed) in ranges.items():
            raw = getattr(self, name)
            if isinstance(raw, bool) or not isinstance(raw, Real) or not math.isfinite(raw):
                raise ValueError(f"{name}: must be a finite number, got {raw!r}")
            v = float(raw)
            if not (low <= v if closed else low < v) or v > high:
                span = f"{'[' if closed else '('}{low:g}, {high:g}]" if high < math.inf else "> 0"
                raise ValueError(f"{name}: must be in {span}, got {raw!r}")

    @property
    def n_states(self) -> int:
        return self.table.shape[0]

    @property
    def states_visited(self) -> int:
        """How many states have been visited at least once."""
        return int(np.count_nonzero(self.visits))

    def state(self, obs: np.ndarray) -> np.ndarray:
        """Flat state index of observations (…, obs_dim)."""
        obs = np.asarray(obs, dtype=float)
        idx = [np.searchsorted(self.bins[d], obs[..., d], side="right") for d in self._dims]
        return np.ravel_multi_index(tuple(idx), self._sizes)

    def epsilon(self) -> float:
        frac = np.exp(-self.episodes / self.epsilon_decay_episodes)
        return float(self.epsilon_end + (self.epsilon_start - self.epsilon_end) * frac)

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Actions for observations (N, obs_dim) or (obs_dim,)."""
        s = self.state(obs)
        greedy = self.table[s].argmax(axis=-1)
        if deterministic:
            return greedy
        explore = self.rng.random(np.shape(greedy)) < self.epsilon()
        random = self.rng.integers(self.n_actions, size=np.shape(greedy))
        return np.where(explore, random, greedy)

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """Stable-Baselines3's ``predict``: ``(actions, state)``, the agent being memoryless.
        What SB3's tools (``evaluate_policy``) and :class:`agents.policy.Policy` call, alike for
        every agent."""
        return self.act(observation, deterministic=deterministic), None

    def update(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """One Q-learning update per transition (arrays over environments)."""
        s = np.atleast_1d(self.state(obs))
        s2 = np.atleast_1d(self.state(next_obs))
        a = np.atleast_1d(action).astype(int)
        r = np.atleast_1d(reward)
        bootstrap = np.where(np.atleast_1d(terminated), 0.0, self.table[s2].max(axis=1))
        np.add.at(self.visits, s, 1)
        self.steps += int(s.size)
        for i in range(s.size):  # sequential: two envs may share a state
            target = r[i] + self.gamma * bootstrap[i]
            self.table[s[i], a[i]] += self.alpha * (target - self.table[s[i], a[i]])

    def save(self, path: str | Path) -> None:
        """Write the agent (``.npz``) atomically."""
        buf = io.BytesIO()
        np.savez(
            buf,
            table=self.table,
            episodes=self.episodes,
            steps=self.steps,
            visits=self.visits,
            n_actions=self.n_actions,
            bins_dims=np.array(self._dims),
            bins_flat=np.concatenate([self.bins[d] for d in self._dims]),
            bins_len=np.array([len(self.bins[d]) for d in self._dims]),
            params=np.array(
                [
                    self.alpha,
                    self.gamma,
                    self.epsilon_start,
                    self.epsilon_end,
                    self.epsilon_decay_episodes,
                    self.seed,
                ]
            ),
            rng_state=np.frombuffer(json.dumps(self.rng.bit_generator.state).encode(), np.uint8),
        )
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> TabularQAgent:
        with np.load(path) as z:
            edges = np.split(z["bins_flat"], np.cumsum(z["bins_len"])[:-1])
            bins = {int(d): list(map(float, e)) for d, e in zip(z["bins_dims"], edges, strict=True)}
            alpha, gamma, e0, e1, ed, seed = z["params"]
            agent = cls(
                n_actions=int(z["n_actions"]),
                bins=bins,
                alpha=float(alpha),
                gamma=float(gamma),
                epsilon_start=float(e0),
                epsilon_end=float(e1),
                epsilon_decay_episodes=float(ed),
                seed=int(seed),
            )
            agent.table = z["table"].copy()
            agent.episodes = int(z["episodes"])
            if "steps" in z:  # files written before the agent counted them have neither
                agent.steps = int(z["steps"])
                agent.visits = z["visits"].astype(np.int64)
            state: dict[str, Any] = json.loads(bytes(z["rng_state"]).decode())
            agent.rng.bit_generator.state = state
        return agent


def _check_bins(bins: Any) -> dict[int, list[float]]:
    """``{observation index: sorted finite bin edges}``; ``ValueError`` naming ``bins``."""
    if not isinstance(bins, dict):
        raise ValueError(f"bins: must be a mapping of observation index to bin edges, got {bins!r}")
    out: dict[int, list[float]] = {}
    for k, edges in bins.items():
        try:
            dim = int(k)
        except (TypeError, ValueError):
            raise ValueError(f"bins: {k!r} is not an observation index") from None
        if dim < 0:
            raise ValueError(f"bins: {k!r} is not an observation index")
        if not isinstance(edges, list | tuple) or not all(
            isinstance(x, Real) and not isinstance(x, bool) and math.isfinite(x) for x in edges
        ):
            raise ValueError(f"bins.{dim}: must be a list of finite numbers, got {edges!r}")
        out[dim] = sorted(float(x) for x in edges)
    return out


def train_tabular(
    agent: TabularQAgent,
    env: Any,
    episodes: int,
    on_episode: Any = None,
    on_step: Callable[[list[float]], None] | None = None,
) -> list[float]:
    """Train on an SB3 ``VecEnv`` (``agents.common.vec_env.make_vec_env``) until ``episodes``
    episodes have ended; returns the return of each finished episode. ``on_episode(n_done)`` is
    called as they finish; ``on_step(returns)`` after every step of the environments, with the
    returns of the episodes that ended at that step (often none)."""
    obs = env.reset()
    returns: list[float] = []
    running = np.zeros(env.num_envs)
    while len(returns) < episodes:
        action = agent.act(obs, deterministic=False)
        next_obs, reward, done, infos = env.step(action)
        final = next_obs.copy()
        terminated = np.zeros(env.num_envs, dtype=bool)
        for i, info in enumerate(infos):
            if done[i]:
                final[i] = info["terminal_observation"]
                terminated[i] = not info.get("TimeLimit.truncated", False)
        agent.update(obs, action, reward, final, terminated)
        running += reward
        finished: list[float] = []
        for j in np.flatnonzero(done):
            finished.append(float(running[j]))
            returns.append(finished[-1])
            running[j] = 0.0
            agent.episodes += 1
            if on_episode is not None:
                on_episode(len(returns))
        if on_step is not None:
            on_step(finished)
        obs = next_obs
    return returns[:episodes]
