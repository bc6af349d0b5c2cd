r"""Minari datasets of ``qkf/TransferAlignment-v4`` episodes driven by a method (``qkf dataset``,
docs/environment.md, "Datasets"): observations, actions and rewards of the environment, for
offline RL and behavioural cloning, in a format others can load (`Minari
<https://minari.farama.org>`_).

A method (``kf``, ``glr``, ``nis-rule``, any spec of ``qkf bench --methods``) filters the
trials of a scenario as in a benchmark; its decisions are then expressed as the environment's
moves (:func:`method_moves`) and replayed through the environment (:func:`record_episodes`),
which gives the observations, rewards and ends of the episodes as an agent would have seen
them. :func:`write_minari` stores the episodes as a Minari dataset (arrow format), and
:func:`make_datasets` does all of it for ``qkf dataset``, one dataset per method.

**What is carried over.** Only κ (the method's κ at each period's first epoch) and resets of
the calibration covariance (``glr``'s re-openings, at the next period's start) are actions of
the environment's space. What a method adapts internally in any other way — the measurement
noise R of ``sage-husa``, the mixing of a bank (``imm``, ``mmae``), a per-term κ — is not an
action of this space and is lost: the replay then filters with that κ and nominal everything
else, so its estimates are not the method's. A method that gives its moves directly (the
hindsight yardstick over the moves) puts them in its logs (:data:`MOVES_LOG`, or
``moves_<field>`` as :meth:`~qkf.transfer_alignment.methods.moves_schedule.MoveSchedule.as_logs`
writes) and they are replayed as they are.

**Actions and moves.** The actions stored are the discrete indices nearest to the moves
(:meth:`~envs.transfer_alignment.controls.ControlMap.actions_of`); the environment is stepped
with the moves themselves, which may lie between the grid's values (``glr``'s reset of
``reset_ppm``) or outside the controlled dimensions (a reset with ``controls="kappa"``). The
moves applied are in each step's ``infos`` (``kappa``, ``q_att``, ``q_bias``, ``r_scale``,
``reset``), and ``infos["on_grid"]`` says whether the stored action gives exactly them.

Reproducible: the same scenario, overrides, seed, trials, controls, reward and period give
identical arrays (trial ``i`` of ``seed`` is simulated from its own seed, whatever the chunk).
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from envs.common.bounds import observation_box
from envs.transfer_alignment import ENV_ID_V4
from envs.transfer_alignment.controls import ControlMap, parse_controls
from envs.transfer_alignment.episodes import DEFAULT_PERIOD_S, EpisodeDriver
from envs.transfer_alignment.observations import OBSERVATIONS
from envs.transfer_alignment.rewards import REWARDS
from qkf.core.config import ConfigError
from qkf.core.io import OutputError, check_output_dir
from qkf.transfer_alignment.adaptive import GlrConfig
from qkf.transfer_alignment.config import MAX_TRIALS, Config, check_workload, load_config
from qkf.transfer_alignment.methods import (
    METHODS,
    MethodOutput,
    NamedMethod,
    prepare,
    resolve_method_settings,
    validate_output,
)
from qkf.transfer_alignment.methods.base import decision_steps, settings_of
from qkf.transfer_alignment.methods.glr import run_glr
from qkf.transfer_alignment.moves import Moves
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import ScenarioData, simulate

NAMESPACE = "qkf"
"""The Minari namespace of the datasets."""
VERSION = 0
"""The version of the dataset ids (``…-v0``)."""
MOVE_FIELDS = ("kappa", "q_att", "q_bias", "r_scale", "reset")
"""The fields of :class:`~qkf.transfer_alignment.moves.Moves`, in order."""
MOVES_LOG = "moves"
"""A method's log of its moves: a dict of arrays (B, T) with the keys :data:`MOVE_FIELDS`, one
column per decision period of the environment (also read: ``moves_<field>`` (B, T) logs)."""
DATA_FORMAT = "arrow"
"""Minari's storage format used (pyarrow; Minari's default, HDF5, needs h5py)."""


# --- a method's decisions as moves --------------------------------------------------------------


def method_moves(cfg: Config, out: MethodOutput, period: int, controls: ControlMap) -> list[Moves]:
    """The decisions of a method's output as the environment's moves, one
    :class:`~qkf.transfer_alignment.moves.Moves` (B,) per decision period of ``period`` epochs.

    With a moves log (:data:`MOVES_LOG`, or ``moves_<field>``) those moves. Otherwise: κ = the
    method's κ (``out.kappa``) at the period's first epoch (the nominal κ of ``controls`` where
    it is not finite and positive: a diverged trial); a reset of fraction
    ``adaptive.glr.reset_ppm · 1e-6 / σ0`` (σ0: the prior σ of the first calibration term) at
    the start of the period after one in which the method re-opened the calibration covariance
    (``out.logs["reopen"]`` (B, N) bool), else none; ``q_att``, ``q_bias`` and ``r_scale``
    nominal (1). Only κ and resets are carried over: what a method adapts in other ways (R of
    ``sage-husa``, a bank's mixing) is not an action of this space (module docstring).

    ``ValueError`` for an output without κ (``out.kappa`` None: see :func:`run_method`) or a
    moves log of the wrong shape.
    """
    b, n = np.shape(out.est)[:2]
    steps = -(-n // period)  # ceil: the last period may be cut short
    logged = _logged_moves(out)
    if logged is not None:
        for name, arr in logged.items():
            if np.shape(arr) != (b, steps):
                raise ValueError(
                    f"moves log {name!r} has shape {np.shape(arr)}, expected ({b}, {steps}): one "
                    f"column per period of {period} epochs"
                )
        cols = [np.asarray(logged[f], dtype=float) for f in MOVE_FIELDS]
        return [Moves(*(c[:, p].copy() for c in cols)) for p in range(steps)]
    if out.kappa is None:
        raise ValueError("the method reports no κ (MethodOutput.kappa is None)")
    kappa = np.asarray(out.kappa, dtype=float)[:, ::period]
    kappa = np.where(np.isfinite(kappa) & (kappa > 0.0), kappa, controls.kappa_nominal)
    reset = np.zeros((b, steps))
    reopen = out.logs.get("reopen")
    if reopen is not None:
        params = FilterParams.from_config(cfg)
        reset_ppm = settings_of(run_glr, cfg, GlrConfig).reset_ppm
        fraction = reset_ppm * 1e-6 / float(params.p0_sigma[6])
        padded = np.zeros((b, steps * period), dtype=bool)
        padded[:, :n] = np.asarray(reopen, dtype=bool)
        within = np.asarray(padded.reshape(b, steps, period).any(axis=2))  # inside period p
        reset[:, 1:] = np.where(within[:, :-1], fraction, 0.0)  # … resets at p + 1's start
    return [
        Moves(kappa[:, p].copy(), np.ones(b), np.ones(b), np.ones(b), reset[:, p].copy())
        for p in range(steps)
    ]


def _logged_moves(out: MethodOutput) -> dict[str, Any] | None:
    """The moves a method logged (:data:`MOVES_LOG` or ``moves_<field>``), or None."""
    logs: dict[str, Any] = dict(out.logs)
    found = logs.get(MOVES_LOG)
    if isinstance(found, dict):
        missing = [f for f in MOVE_FIELDS if f not in found]
        if missing:
            raise ValueError(f"moves log without {', '.join(missing)}")
        return {f: found[f] for f in MOVE_FIELDS}
    flat = {f: logs.get(f"moves_{f}") for f in MOVE_FIELDS}
    if all(v is not None for v in flat.values()):
        return flat
    return None


def run_method(cfg: Config, named: NamedMethod, data: ScenarioData) -> MethodOutput:
    """``named``'s (prepared) method on ``data``, its output checked against the contract and
    its κ filled in where it reports none but holds one constant: ``kf`` (``run.kappa``) and a
    method prepared to a fixed κ (``kf-tuned``: its ``kappa``). ``ValueError`` for another
    method without κ (it cannot be replayed as moves)."""
    out = validate_output(named.method(cfg, data), named.name, data.n_trials, data.n_epochs)
    if out.kappa is None and not _logged_moves(out):
        fixed = getattr(named.method, "kappa", None)
        if named.method is METHODS["kf"]:
            fixed = cfg.run.kappa
        if not isinstance(fixed, int | float):
            raise ValueError(
                f"method {named.name!r} reports no κ (MethodOutput.kappa is None) and no moves: "
                "it cannot be replayed through the environment"
            )
        out.kappa = np.full((data.n_trials, data.n_epochs), float(fixed))
    return out


def method_config(cfg: Config, method: object) -> Config:
    """The config a (prepared) method runs with: ``cfg``, or for an Optuna-tuned method
    (``glr-tuned``) ``cfg`` with its tuned settings written in (its ``reset_ppm``, which
    :func:`method_moves` reads)."""
    from qkf.transfer_alignment.methods.tuned import TunedSetting

    if isinstance(method, TunedSetting):
        return method.tuner.build(cfg, dict(method.settings))[0]
    return cfg


# --- episodes ------------------------------------------------------------------------------------


@dataclass
class EpisodeBuffers:
    """B episodes of T steps at most (the environment's ``episode_steps``), padded to T:
    episode i has ``lengths[i]`` steps, ending at its termination or truncation.

    ``infos`` has one row per observation (T + 1): row 0 is the reset's (as the environment's
    ``reset`` info: κ 1, nominal moves, t 0; errors and CRLB NaN), row t + 1 step t's.
    """

    observations: np.ndarray  # (B, T + 1, 24) float32
    actions: np.ndarray  # (B, T) for a Discrete action space, else (B, T, D); int64
    rewards: np.ndarray  # (B, T)
    terminations: np.ndarray  # (B, T) bool
    truncations: np.ndarray  # (B, T) bool
    infos: dict[str, np.ndarray]  # each (B, T + 1, …)
    lengths: np.ndarray  # (B,) steps of each episode
    trial_ids: np.ndarray  # (B,) the trial each episode replays
    est: np.ndarray | None = field(default=None, repr=False)  # (B, N, 16) the env's estimates

    @property
    def n_episodes(self) -> int:
        return int(self.rewards.shape[0])

    def episode(self, i: int) -> dict[str, Any]:
        """Episode ``i``'s arrays, cut to its length (the keys of a Minari episode)."""
        n = int(self.lengths[i])
        return {
            "observations": self.observations[i, : n + 1],
            "actions": self.actions[i, :n],
            "rewards": self.rewards[i, :n],
            "terminations": self.terminations[i, :n],
            "truncations": self.truncations[i, :n],
            "infos": {k: v[i, : n + 1] for k, v in self.infos.items()},
        }

    @classmethod
    def concatenate(cls, parts: Sequence[EpisodeBuffers]) -> EpisodeBuffers:
        """The episodes of ``parts`` (chunks of trials of one scenario), in order."""

        def cat(get: Callable[[EpisodeBuffers], np.ndarray | None]) -> Any:
            arrays = [a for a in (get(p) for p in parts) if a is not None]
            return np.concatenate(arrays) if len(arrays) == len(parts) else None

        return cls(
            observations=cat(lambda p: p.observations),
            actions=cat(lambda p: p.actions),
            rewards=cat(lambda p: p.rewards),
            terminations=cat(lambda p: p.terminations),
            truncations=cat(lambda p: p.truncations),
            infos={k: cat(lambda p, k=k: p.infos[k]) for k in parts[0].infos},  # type: ignore[misc]
            lengths=cat(lambda p: p.lengths),
            trial_ids=cat(lambda p: p.trial_ids),
            est=cat(lambda p: p.est),
        )


def record_episodes(
    cfg: Config,
    data: ScenarioData,
    moves_per_period: Sequence[Moves],
    controls_spec: str,
    reward: str,
    period_s: float = DEFAULT_PERIOD_S,
    keep_estimates: bool = False,
) -> EpisodeBuffers:
    """Replay the B trials of ``data`` through ``qkf/TransferAlignment-v4`` (discrete actions,
    ``controls_spec``, ``reward``, ``period_s``), one decision period per entry of
    ``moves_per_period`` (one :class:`Moves` (B,) each; as many as the episode has steps):
    the environment applies exactly those moves; the actions recorded are the discrete indices
    nearest to them (module docstring). ``keep_estimates``: also keep the filter's estimates
    over the episodes (``est`` (B, N, 16), for checks). ``ValueError`` for a wrong number of
    periods or an episode that neither ends nor is truncated."""
    b = data.n_trials
    driver = EpisodeDriver(
        n=b, scenario=cfg, action_type="discrete", reward=reward, overrides=None,
        period_s=period_s, observation="v4", controls=controls_spec,
    )  # fmt: skip
    controls = driver.controls
    assert controls is not None
    steps = driver.episode_steps
    if len(moves_per_period) != steps:
        raise ValueError(f"{len(moves_per_period)} periods of moves for episodes of {steps} steps")
    discrete = isinstance(controls.space, spaces.Discrete)
    obs = np.empty((b, steps + 1, driver.observation_space.shape[0]), dtype=np.float32)
    actions = np.zeros((b, steps, controls.size), dtype=np.int64)
    rewards = np.zeros((b, steps))
    terminated = np.zeros((b, steps), dtype=bool)
    truncated = np.zeros((b, steps), dtype=bool)
    infos = {
        "kappa": np.ones((b, steps + 1)),  # the reset row as the environment's reset info
        **{f: np.ones((b, steps + 1)) for f in MOVE_FIELDS[1:4]},
        "reset": np.zeros((b, steps + 1)),
        "t_s": np.zeros((b, steps + 1)),
        "diverged": np.zeros((b, steps + 1), dtype=bool),
        "on_grid": np.ones((b, steps + 1), dtype=bool),
        "errors": np.full((b, steps + 1, 15), np.nan),
        "crlb": np.full((b, steps + 1, 15), np.nan),
    }
    est = []
    obs[:, 0] = driver.core.load(data)
    for t, moves in enumerate(moves_per_period):
        act = controls.actions_of(moves)
        out = driver.step_moves(moves)
        obs[:, t + 1] = out.obs
        actions[:, t] = act
        rewards[:, t] = out.reward
        terminated[:, t], truncated[:, t] = out.terminated, out.truncated
        for name, value in zip(MOVE_FIELDS, moves.fields(), strict=True):
            infos[name][:, t + 1] = value
        infos["t_s"][:, t + 1] = out.t_s
        infos["diverged"][:, t + 1] = out.terminated
        infos["on_grid"][:, t + 1] = _on_grid(controls, act, moves)
        infos["errors"][:, t + 1] = out.errors
        infos["crlb"][:, t + 1] = out.crlb
        if keep_estimates:
            est.append(out.est)
    done = terminated | truncated
    if not done.any(axis=1).all():
        raise ValueError("an episode neither terminated nor was truncated at its last step")
    lengths = done.argmax(axis=1) + 1  # each episode ends at its first end
    return EpisodeBuffers(
        observations=obs,
        actions=actions[:, :, 0] if discrete else actions,
        rewards=rewards,
        terminations=terminated,
        truncations=truncated,
        infos=infos,
        lengths=lengths,
        trial_ids=np.asarray(data.trial_ids, dtype=np.int64),
        est=np.concatenate(est, axis=1)[:, : data.n_epochs] if keep_estimates else None,
    )


def _on_grid(controls: ControlMap, actions: np.ndarray, moves: Moves) -> np.ndarray:
    """Whether ``actions`` (N, D) give exactly ``moves`` (to rounding), per episode."""
    back = controls.moves(actions, actions.shape[0])
    return np.logical_and.reduce(
        [np.isclose(a, m, rtol=1e-9, atol=0.0) for a, m in zip(back.fields(), moves.fields(),
                                                                strict=True)]
    )  # fmt: skip


# --- Minari ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DatasetInfo:
    """What a dataset's metadata records, besides its episodes: the environment it was made
    with (``env_kwargs``: ``gym.make(ENV_ID_V4, **env_kwargs)`` remakes it), the method and
    the trials."""

    method: str  # the label
    method_spec: str | None
    scenario: str  # as given: a preset name or a config path
    overrides: tuple[str, ...]
    seed: int
    trial_ids: tuple[int, ...]
    controls: str
    reward: str
    period_s: float
    observation_space: spaces.Box
    action_space: spaces.Space[Any]
    dimensions: tuple[tuple[str, tuple[float, ...]], ...]  # each action dimension's grid

    @property
    def env_kwargs(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "overrides": list(self.overrides),
            "action_type": "discrete",
            "reward": self.reward,
            "period_s": self.period_s,
            "observation": "v4",
            "controls": self.controls,
        }

    def metadata(self) -> dict[str, Any]:
        """The ``qkf`` entry of the dataset's metadata (JSON)."""
        return {
            "environment": ENV_ID_V4,
            "env_kwargs": self.env_kwargs,
            "method": self.method,
            "method_spec": self.method_spec,
            "scenario": self.scenario,
            "overrides": list(self.overrides),
            "seed": self.seed,
            "trial_ids": list(self.trial_ids),
            "controls": self.controls,
            "reward": self.reward,
            "period_s": self.period_s,
            "action_dimensions": [name for name, _ in self.dimensions],
            "action_grids": {name: list(grid) for name, grid in self.dimensions},
            "infos": "row 0: reset; row t+1: step t. kappa, q_att, q_bias, r_scale, reset: the "
            "moves applied; on_grid: the action gives exactly them; errors, crlb: display units",
        }


def env_spec(info: DatasetInfo) -> Any:
    """The Gymnasium spec of the environment the dataset's episodes come from."""
    import gymnasium as gym

    import envs  # noqa: F401  (registers the ids)

    spec = gym.spec(ENV_ID_V4)
    return dataclasses.replace(spec, kwargs={**spec.kwargs, **info.env_kwargs})


@contextmanager
def datasets_path(root: Path) -> Iterator[None]:
    """``MINARI_DATASETS_PATH`` set to ``root`` inside the block (restored after it)."""
    key = "MINARI_DATASETS_PATH"
    before = os.environ.get(key)
    os.environ[key] = str(root)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = before


def write_minari(
    root: Path,
    dataset_id: str,
    episodes: EpisodeBuffers,
    info: DatasetInfo,
    author: str | None = None,
    code_permalink: str | None = None,
) -> Path:
    """Write ``episodes`` as the Minari dataset ``dataset_id`` under the datasets folder
    ``root`` (``MINARI_DATASETS_PATH`` is set to it for the call only); returns the dataset's
    folder. ``FileExistsError`` if it exists (a dataset is never replaced)."""
    import minari
    from minari.data_collector.episode_buffer import EpisodeBuffer

    folder = Path(root) / dataset_id
    if folder.exists():
        raise FileExistsError(f"{folder}: the dataset {dataset_id} exists")
    buffers = []
    for i in range(episodes.n_episodes):
        ep = episodes.episode(i)
        buffers.append(
            EpisodeBuffer(
                id=i,
                observations=ep["observations"],
                actions=ep["actions"],
                rewards=ep["rewards"],
                terminations=ep["terminations"],
                truncations=ep["truncations"],
                # one-value entries as lists: Minari's arrow storage reads a 1-D array back
                # only as a list
                infos={k: (v.tolist() if v.ndim == 1 else v) for k, v in ep["infos"].items()},
            )
        )
    description = (
        f"{episodes.n_episodes} episodes of {ENV_ID_V4} (scenario {info.scenario}, seed "
        f"{info.seed}) driven by the method {info.method}; controls {info.controls}, reward "
        f"{info.reward}, a step every {info.period_s:g} s. Written by qkf dataset."
    )
    with datasets_path(Path(root)), warnings.catch_warnings():
        # Minari warns for every optional field left out (author, e-mail, eval env …)
        warnings.simplefilter("ignore", UserWarning)
        dataset = minari.create_dataset_from_buffers(
            dataset_id=dataset_id,
            buffer=buffers,
            env=None,  # not made here: the spec is recorded below (gym.make would build it)
            algorithm_name=info.method,
            author=author,
            code_permalink=code_permalink,
            action_space=info.action_space,
            observation_space=info.observation_space,
            description=description,
            data_format=DATA_FORMAT,
        )
        storage = dataset.storage
        storage.update_metadata({"env_spec": env_spec(info).to_json(), "qkf": info.metadata()})
        storage.update_episode_metadata(
            [{"trial_id": int(t), "scenario_seed": info.seed} for t in episodes.trial_ids],
            range(episodes.n_episodes),
        )
    return folder


# --- qkf dataset -------------------------------------------------------------------------------


_UNSAFE = re.compile(r"[^A-Za-z0-9_-]+")


def id_part(text: str) -> str:
    """``text`` as a part of a dataset id: letters, digits, ``_`` and ``-`` (others → ``-``)."""
    return _UNSAFE.sub("-", text).strip("-")


def scenario_label(scenario: str) -> str:
    """The scenario's part of the dataset ids: a preset's name, a config file's stem."""
    path = Path(scenario)
    return path.stem if path.suffix in (".yaml", ".yml") else scenario


def dataset_id(scenario: str, method: str) -> str:
    """``qkf/transfer-alignment-v4-{scenario}-{method}-v0``."""
    return (
        f"{NAMESPACE}/transfer-alignment-v4-{id_part(scenario_label(scenario))}-"
        f"{id_part(method)}-v{VERSION}"
    )


@dataclass(frozen=True)
class DatasetPlan:
    """Everything ``qkf dataset`` does, checked before any work (:func:`plan_datasets`)."""

    cfg: Config
    scenario: str
    overrides: tuple[str, ...]
    methods: tuple[NamedMethod, ...]
    ids: tuple[str, ...]
    trials: int
    seed: int
    controls: str
    reward: str
    period_s: float
    out: Path

    def targets(self) -> list[Path]:
        """The datasets' folders."""
        return [self.out / i for i in self.ids]

    @property
    def chunks(self) -> int:
        """Chunks of trials each method runs in (``run.chunk_trials`` each)."""
        return -(-self.trials // self.cfg.run.chunk_trials)


def plan_datasets(
    scenario: str,
    methods: str,
    trials: int | None,
    seed: int | None,
    controls: str,
    reward: str,
    period_s: float,
    out: str | Path,
    overrides: Sequence[str] = (),
) -> DatasetPlan:
    """Check every input of ``qkf dataset`` before any work; :class:`ConfigError` naming the
    option (``--methods: …``) or the config's field. Nothing is written. ``trials``, ``seed``:
    None for the config's ``run.trials``, ``run.seed``."""
    from qkf.transfer_alignment.benchmark import parse_methods

    if trials is not None and not 1 <= trials <= MAX_TRIALS:
        raise ConfigError(f"--trials must be between 1 and {MAX_TRIALS:,}")
    if seed is not None and not 0 <= seed < 2**63:
        raise ConfigError("--seed must be between 0 and 2**63 - 1")
    try:
        parse_controls(controls)
    except ValueError as exc:
        raise ConfigError(f"--controls: {exc}") from None
    if reward not in REWARDS:
        raise ConfigError(
            f"--reward: unknown reward {reward!r}; known: {', '.join(REWARDS.names())}"
        )
    if not (np.isfinite(period_s) and period_s > 0.0):
        raise ConfigError(f"--period-s must be positive, got {period_s!r}")
    cfg = load_config(scenario, list(overrides))  # ConfigError naming the file and field
    trials = cfg.run.trials if trials is None else trials
    seed = cfg.run.seed if seed is None else seed
    try:
        named = parse_methods(methods)
    except ValueError as exc:
        raise ConfigError(f"--methods: {exc}") from None
    try:
        cfg = resolve_method_settings(cfg, named, scenario)
    except ValueError as exc:  # ConfigError, or a method's malformed settings declaration
        raise ConfigError(
            str(exc) if isinstance(exc, ConfigError) else f"--methods: {exc}"
        ) from None
    check_workload(cfg, trials)
    ids = tuple(dataset_id(scenario, m.name) for m in named)
    for m in named:
        if not id_part(m.name):
            raise ConfigError(f"--methods: {m.name!r} gives no dataset name; label it (LABEL=SPEC)")
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        raise ConfigError(f"--methods: two methods give the dataset id {twice[0]}; label them")
    try:
        folder = check_output_dir(out)
    except OutputError as exc:
        raise ConfigError(f"--out: {exc}") from None
    ns = folder / NAMESPACE
    if ns.exists() and not ns.is_dir():
        raise ConfigError(f"--out: {ns} exists and is not a folder (Minari's namespace)")
    for i in ids:
        if (folder / i).exists():
            raise ConfigError(
                f"--out: {folder / i} exists: the dataset {i} was written before; a dataset is "
                "never replaced (remove it, or give another --out)"
            )
    return DatasetPlan(
        cfg=cfg, scenario=scenario, overrides=tuple(overrides), methods=tuple(named), ids=ids,
        trials=trials, seed=seed, controls=controls, reward=reward, period_s=period_s,
        out=folder,
    )  # fmt: skip


def dataset_of(
    plan: DatasetPlan, named: NamedMethod, advance: Callable[[], None] = lambda: None
) -> tuple[EpisodeBuffers, DatasetInfo]:
    """The episodes of one method over the plan's trials (in chunks of ``run.chunk_trials``;
    ``advance()`` after each) and what its dataset records."""
    cfg = plan.cfg
    method = NamedMethod(named.name, prepare(named.method, cfg), named.spec)
    period = decision_steps(plan.period_s, cfg.scenario.dt_s)
    ids = np.arange(plan.trials)
    parts = []
    controls = ControlMap(cfg, plan.controls, "discrete")
    for k0 in range(0, plan.trials, cfg.run.chunk_trials):
        data = simulate(cfg, plan.seed, ids[k0 : k0 + cfg.run.chunk_trials])
        out = run_method(cfg, method, data)
        moves = method_moves(method_config(cfg, method.method), out, period, controls)
        parts.append(record_episodes(cfg, data, moves, plan.controls, plan.reward, plan.period_s))
        advance()
    info = DatasetInfo(
        method=named.name,
        method_spec=named.spec,
        scenario=plan.scenario,
        overrides=plan.overrides,
        seed=plan.seed,
        trial_ids=tuple(int(i) for i in ids),
        controls=plan.controls,
        reward=plan.reward,
        period_s=plan.period_s,
        observation_space=observation_box(OBSERVATIONS["v4"].size),
        action_space=controls.space,
        dimensions=tuple((d.name, tuple(float(g) for g in d.grid)) for d in controls.dims),
    )
    return EpisodeBuffers.concatenate(parts), info


def make_datasets(
    plan: DatasetPlan,
    on_method: Callable[[str, int], Callable[[], None]] | None = None,
    author: str | None = None,
    code_permalink: str | None = None,
) -> list[Path]:
    """Write one dataset per method of ``plan`` into ``plan.out`` (the datasets folder); returns
    their folders. They are written into a staging folder inside ``plan.out`` and moved into
    place together at the end: an error or Ctrl-C leaves nothing behind. ``on_method(label,
    total)``: called as each method starts, returns the ``advance()`` of its progress (called
    ``total`` times: once per chunk of trials, once for the writing)."""
    created = not plan.out.exists()
    plan.out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".qkf-dataset-", dir=plan.out))
    try:
        for named, i in zip(plan.methods, plan.ids, strict=True):
            advance = on_method(named.name, plan.chunks + 1) if on_method else lambda: None
            episodes, info = dataset_of(plan, named, advance)
            write_minari(staging, i, episodes, info, author, code_permalink)
            advance()
        return _publish(staging, plan)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if created and not any(plan.out.iterdir()):
            plan.out.rmdir()
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _publish(staging: Path, plan: DatasetPlan) -> list[Path]:
    """Move the staged datasets (and Minari's namespace record, if the folder has none) into
    ``plan.out``; ``FileExistsError`` (before moving any) if a dataset appeared meanwhile."""
    from minari.namespace import NAMESPACE_METADATA_FILENAME

    targets = plan.targets()
    for t in targets:
        if t.exists():
            raise FileExistsError(f"{t}: appeared while the datasets were made; not replaced")
    ns = plan.out / NAMESPACE
    ns.mkdir(exist_ok=True)
    record = ns / NAMESPACE_METADATA_FILENAME
    if not record.exists():
        os.rename(staging / NAMESPACE / NAMESPACE_METADATA_FILENAME, record)
    for i, t in zip(plan.ids, targets, strict=True):
        os.rename(staging / i, t)
    return targets


class Datasets:
    """``qkf/TransferAlignment-v4``'s ``qkf dataset`` (its ``datasets`` entry in
    :data:`envs.ENVIRONMENTS`): :func:`plan_datasets` and :func:`make_datasets`."""

    plan = staticmethod(plan_datasets)
    make = staticmethod(make_datasets)


DATASETS = Datasets()
