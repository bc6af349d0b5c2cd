r"""Tabular Q-learning agent: the QKF's learner as an episodic agent over the environment.

The observation is discretised on chosen dimensions (``bins``: observation index → bin edges);
the state is the tuple of bin indices, flattened. Learning is one-step Q-learning with an
ε-greedy behaviour policy whose ε decays exponentially per episode::

    Q(s, a) += α (r + γ (1 − terminated) max_a' Q(s', a') − Q(s, a))

``act(obs, deterministic=True)`` is greedy, ties broken towards the lowest action. Everything
random comes from the agent's own generator (``seed``), so training is reproducible. The agent
counts what it has learned from: ``episodes`` ended, ``steps`` (transitions, i.e. environment
steps) and ``visits`` per state; all three are saved with it.

It keeps Stable-Baselines3's model contract, so one training runner serves it and the SB3
algorithms alike (``agents/training/runner.py``; docs/environment.md, "Training and
evaluation"): the constructor takes the ``env`` (an SB3 ``VecEnv``), ``seed``,
``tensorboard_log`` and ``device``; ``learn(total, callback=, progress_bar=,
reset_num_timesteps=)`` calls SB3 callbacks at SB3's points; ``save``/``load``/``predict``;
``num_timesteps``, ``get_env``, ``set_env``, ``set_random_seed``, ``logger``. Two things differ,
and the algorithm registry says so (``agents.algorithms.ALGORITHMS["tabular"]``): ``learn``
counts *episodes*, not steps, and a "rollout" is the steps up to one that ends an episode, so
callbacks that act between rollouts (the run's checkpoints and evaluations) never cut an episode
short. Without a callback or a TensorBoard folder the agent imports neither SB3 nor torch.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path
from typing import IO, Any

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


def _episode_return(info: dict[str, Any], running: float) -> float:
    """An ended episode's return: the ``VecMonitor``'s (the environment's reward, before a
    learner's scaling) if it recorded one, else the sum of the rewards learned from."""
    episode = info.get("episode")
    return float(episode["r"]) if episode is not None else float(running)


@dataclass
class TabularQAgent:
    """Q-learning over binned observations; SB3's model contract (see the module docstring).

    ``n_actions``: the number of discrete actions (None: from ``env``'s action space); ``bins``:
    observation index → bin edges; ``alpha``, ``gamma``: learning rate and discount;
    ``epsilon_*``: exploration, ``ε = end + (start − end) exp(−episodes / decay_episodes)``;
    ``seed``: the agent's own generator; ``env``, ``tensorboard_log``, ``device``: as SB3's.
    """

    n_actions: int | None = None
    bins: dict[int, list[float]] = field(default_factory=lambda: dict(DEFAULT_BINS))
    alpha: float = 0.1
    gamma: float = 0.9
    epsilon_start: float = 0.3
    epsilon_end: float = 0.02
    epsilon_decay_episodes: float = 30.0
    seed: int = 0
    env: Any = field(default=None, repr=False)  # the SB3 VecEnv it learns on
    tensorboard_log: str | None = None  # folder of its TensorBoard runs (SB3's argument)
    device: str = "cpu"  # SB3's argument: the table is a numpy array on the CPU
    table: np.ndarray = field(init=False)
    episodes: int = field(init=False, default=0)
    steps: int = field(init=False, default=0)
    visits: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        if self.env is not None:
            self.n_actions = self._env_actions(self.env, self.n_actions)
        if self.n_actions is None:
            raise ValueError("n_actions: needed when no env is given")
        if self.device not in ("cpu", "auto"):
            raise ValueError(f"device: the tabular agent runs on the CPU, got {self.device!r}")
        if self.n_actions < 2:
            raise ValueError("n_actions: must be at least 2")
        self._check_numbers()
        self.bins = _check_bins(self.bins)
        self._dims = sorted(self.bins)
        self._sizes = [len(self.bins[d]) + 1 for d in self._dims]
        self.table = np.zeros((int(np.prod(self._sizes)), self.n_actions))
        self.visits = np.zeros(self.table.shape[0], dtype=np.int64)
        self.rng = np.random.default_rng(self.seed)
        self.logger: Any = None  # SB3's Logger while it learns with a callback or TensorBoard
        # SB3's: where the last learn stopped, so the next one goes on from there (None: reset)
        self._last_obs: np.ndarray | None = None
        self._returns: np.ndarray | None = None  # the running episodes' returns so far

    @staticmethod
    def _env_actions(env: Any, n_actions: int | None) -> int:
        """The number of actions of ``env``; ``ValueError`` if it is not discrete or disagrees
        with ``n_actions``."""
        n = getattr(env.action_space, "n", None)
        if n is None:
            raise ValueError(f"env: the tabular agent needs discrete actions: {env.action_space}")
        if n_actions is not None and int(n) != n_actions:
            raise ValueError(f"n_actions: {n_actions}, but the env has {int(n)} actions")
        return int(n)

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
        random = self.rng.integers(self.table.shape[1], size=np.shape(greedy))
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

    # ------------------------------------------------------------------------------------------
    # Stable-Baselines3's model contract

    @property
    def num_timesteps(self) -> int:
        """Environment steps learned from (SB3's counter; what evaluations are indexed by)."""
        return self.steps

    def get_env(self) -> Any:
        """The ``VecEnv`` it learns on (None: not set)."""
        return self.env

    def set_env(self, env: Any) -> None:
        """Learn on ``env`` from now on; ``ValueError`` if its actions do not fit the table."""
        self._env_actions(env, self.n_actions)
        self.env = env
        self._last_obs = self._returns = None  # the next learn starts new episodes

    def get_vec_normalize_env(self) -> Any:
        """None: no observation normalisation (SB3's evaluation callback asks)."""
        return None

    def set_random_seed(self, seed: int | None = None) -> None:
        """Seed the environment (SB3's ``set_random_seed``). The agent's own generator goes on
        from its state, which :meth:`save` keeps: a resumed run explores reproducibly."""
        if seed is not None and self.env is not None:
            self.env.seed(seed)

    def learn(
        self,
        total_episodes: int,
        callback: Any = None,
        tb_log_name: str = "tabular",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> TabularQAgent:
        """Learn on ``env`` until ``total_episodes`` more episodes have ended (its environments
        run in step, so the last step may end a few more; ``episodes`` says how many).

        SB3's ``learn``, counting episodes: ``callback`` (an SB3 callback or a list of them)
        is called at SB3's points, a rollout being the steps up to one at which an episode
        ends; ``reset_num_timesteps`` says whether the TensorBoard log starts a new run or
        continues the last (the counters, which set ε, always go on). As in SB3, the
        environment is reset when ``reset_num_timesteps`` or on the first call; otherwise the
        episodes go on from where the last call stopped. ``progress_bar`` counts episodes.
        Each ended episode's return (the environment's own, before any reward scaling: the
        ``VecMonitor``'s when there is one), and then ε, the states visited and the episodes,
        go to the TensorBoard log (``tensorboard_log``) at the step count.
        """
        if self.env is None:
            raise ValueError("env: the agent has no environment to learn on (set_env)")
        from rich.progress import Progress

        env = self.env
        hooks = self._callback(callback, tb_log_name, reset_num_timesteps)
        target = self.episodes + total_episodes
        hooks.on_training_start(locals(), globals())
        if reset_num_timesteps or self._last_obs is None or self._returns is None:
            self._last_obs, self._returns = env.reset(), np.zeros(env.num_envs)
        obs, running = self._last_obs, self._returns
        hooks.on_rollout_start()
        with Progress(disable=not progress_bar) as bar:
            task = bar.add_task("tabular episodes", total=target, completed=self.episodes)
            while self.episodes < target:
                actions = self.act(obs, deterministic=False)
                # SB3's names for these: its callbacks read them from locals
                new_obs, rewards, dones, infos = env.step(actions)
                final = new_obs.copy()  # the transition's next state: the terminal one
                terminated = np.zeros(env.num_envs, dtype=bool)
                for i in np.flatnonzero(dones):
                    final[i] = infos[i]["terminal_observation"]
                    terminated[i] = not infos[i].get("TimeLimit.truncated", False)
                self.update(obs, actions, rewards, final, terminated)
                running += rewards
                finished = [_episode_return(infos[i], running[i]) for i in np.flatnonzero(dones)]
                running[dones] = 0.0
                self.episodes += len(finished)
                self._log(finished)
                bar.update(task, completed=self.episodes)
                hooks.update_locals(locals())
                obs = self._last_obs = new_obs
                if not hooks.on_step():
                    break
                if finished:  # an episode ended: so does the rollout
                    hooks.on_rollout_end()
                    if self.episodes < target:
                        hooks.on_rollout_start()
        hooks.on_training_end()
        return self

    def _callback(self, callback: Any, tb_log_name: str, reset_num_timesteps: bool) -> Any:
        """The callback ready to call (SB3's ``_init_callback``), and SB3's logger if there is
        a callback or a TensorBoard folder; neither: no SB3 import, and hooks that do nothing."""
        if callback is None and self.tensorboard_log is None:
            self.logger = None
            return _NoCallback()
        from stable_baselines3.common.callbacks import CallbackList
        from stable_baselines3.common.utils import configure_logger

        self.logger = configure_logger(0, self.tensorboard_log, tb_log_name, reset_num_timesteps)
        if callback is None:
            return _NoCallback()
        if isinstance(callback, list):
            callback = CallbackList(callback)
        callback.init_callback(self)
        return callback

    def _log(self, finished: list[float]) -> None:
        """TensorBoard: the returns of the episodes that just ended, then ε, the states visited
        and the episodes, at the current step count."""
        if self.logger is None or not finished:
            return
        for ret in finished:
            self.logger.record("rollout/ep_return", ret)
            self.logger.dump(self.steps)
        self.logger.record("train/epsilon", self.epsilon())
        self.logger.record("train/states_visited", self.states_visited)
        self.logger.record("train/episodes", self.episodes)
        self.logger.dump(self.steps)

    # ------------------------------------------------------------------------------------------
    # files

    def save(self, path: str | Path | IO[bytes]) -> None:
        """Write the agent (``.npz``; a path without a suffix gets it, as SB3's ``.zip``):
        atomically to a path, or into a binary file object."""
        buf = io.BytesIO()
        np.savez(
            buf,
            table=self.table,
            episodes=self.episodes,
            steps=self.steps,
            visits=self.visits,
            n_actions=self.table.shape[1],
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
        if isinstance(path, str | Path):
            path = Path(path)
            atomic_write_bytes(path if path.suffix else path.with_suffix(".npz"), buf.getvalue())
        else:
            path.write(buf.getvalue())

    @classmethod
    def load(
        cls,
        path: str | Path | IO[bytes],
        env: Any = None,
        device: str = "cpu",
        tensorboard_log: str | None = None,
    ) -> TabularQAgent:
        """An agent saved by :meth:`save`, set to learn on ``env`` (SB3's ``load``)."""
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
                env=env,
                tensorboard_log=tensorboard_log,
                device=device,
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


class _NoCallback:
    """SB3's callback hooks, doing nothing: :meth:`TabularQAgent.learn` without a callback."""

    def on_step(self) -> bool:
        return True  # go on

    def __getattr__(self, name: str) -> Any:
        return lambda *args: None  # on_training_start, on_rollout_start, update_locals, …
