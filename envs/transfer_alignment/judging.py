"""A saved κ policy over transfer-alignment trials: ``policy:PATH`` of ``qkf bench`` and the
studies (docs/methods.md, "Learned policies").

The policy sees the observation of the environment id it was trained on (the batched episodes
of :mod:`envs.transfer_alignment.episodes`, with that id's observation version and options)
every decision period, and its action sets κ for the next period; everything else is the filter
of every other method, run on the same simulated trials. A v4 policy makes the environment's
moves instead (its ``controls`` on top of its ``base`` rule). The environment registry names
:func:`run_policy` as the transfer-alignment ids' ``policy_runner``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from envs.common import ActingPolicy, ActionMap
from envs.transfer_alignment.episodes import BatchedEpisodes, EpisodeDriver
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput, per_epoch
from qkf.transfer_alignment.methods.moves_schedule import MoveSchedule, run_moves
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.scenario import ScenarioData


def check_policy(options: Mapping[str, Any], cfg: Config, n_actions: int | None = None) -> None:
    """Whether a saved policy of environment ``options`` choosing among ``n_actions`` discrete
    actions can run on ``cfg`` (before any work): ``TypeError`` for another problem's config,
    ``ValueError`` for an environment without an observation version or another action set
    (``adaptive.actions``; v4's ``controls`` make their own moves)."""
    if not isinstance(cfg, Config):
        raise TypeError("a transfer-alignment policy runs over transfer-alignment trials only")
    if options.get("observation") is None:
        raise ValueError("its environment has no observation version")
    values = np.asarray(cfg.adaptive.actions.values())
    if n_actions is not None and options.get("controls") is None and n_actions != values.size:
        raise ValueError(
            f"chooses among {n_actions} actions, but the config's action set "
            f"(adaptive.actions) has {values.size}: a policy trained on another action set"
        )


def run_policy(
    policy: ActingPolicy,
    options: Mapping[str, Any],
    cfg: Config,
    data: ScenarioData,
    n_actions: int | None = None,
    describe: str = "policy",
) -> MethodOutput:
    """Filter the trials of ``data`` with κ chosen by ``policy`` (module docstring);
    ``options``: the environment's (``observation``, ``action_type``, ``period_s``, and
    ``controls``/``base`` for v4). ``TypeError`` for another problem's config or data;
    ``ValueError`` when a policy of ``n_actions`` discrete actions meets another action set."""
    if not isinstance(data, ScenarioData):
        raise TypeError("a transfer-alignment policy runs over transfer-alignment trials only")
    check_policy(options, cfg, n_actions)
    observation = str(options["observation"])
    if options.get("controls") is not None:  # v4: the policy makes the filter's moves
        return _run_moves_policy(policy, options, cfg, data, observation, describe)
    values = np.asarray(cfg.adaptive.actions.values())
    actions = ActionMap(values, str(options["action_type"]))
    core = BatchedEpisodes(
        cfg, data.n_trials, "likelihood", float(options["period_s"]), observation=observation
    )
    obs = core.load(data)
    policy.reset(data.n_trials)
    est = np.full((data.n_trials, data.n_epochs, 16), np.nan)
    kappa_log = []
    for k0 in range(0, data.n_epochs, core.period):
        mapped = [actions(a) for a in policy.act(obs)]
        kappa = np.array([m[0] for m in mapped])
        kappa_log.append(kappa)
        out = core.step(kappa, np.array([m[1] for m in mapped]))
        k1 = min(data.n_epochs, k0 + core.period)
        est[:, k0:k1] = out.est[:, : k1 - k0]
        obs = out.obs
    kappa = per_epoch(np.stack(kappa_log, axis=1), core.period, data.n_epochs)
    # the covariance the policy's filter believes, for NEES: the filter is deterministic given
    # its κ per epoch, so replaying that schedule reproduces it (same estimates, tested), and
    # the episode machinery need not record covariances at the sampled epochs itself
    replay = run_schedule(cfg, data, kappa)
    return MethodOutput(
        est=est,
        diverged=core.kf.diverged.copy(),
        kappa=kappa,
        notes={"policy": describe},
        cov=replay.cov,
        var=replay.var,
        innov=replay.innov,
        nis=replay.nis,
    )


def _run_moves_policy(
    policy: ActingPolicy,
    options: Mapping[str, Any],
    cfg: Config,
    data: ScenarioData,
    observation: str,
    describe: str,
) -> MethodOutput:
    """A v4 policy: its actions are moves of the environment's ``controls`` (a residual's on
    top of its ``base`` rule), made in the same episodes as in training; the output is
    :func:`~qkf.transfer_alignment.methods.moves_schedule.run_moves` of the moves it made
    (the same filter run, so the same estimates, with the covariance recorded)."""
    driver = EpisodeDriver(
        data.n_trials, cfg, str(options["action_type"]), "oracle", None,
        float(options["period_s"]), observation, controls=options["controls"],
        base=options.get("base"),
    )  # fmt: skip
    assert driver.controls is not None
    n = data.n_trials
    obs = driver.core.load(data)
    driver.restart_base(np.arange(n))
    policy.reset(n)
    made = []
    for _ in range(0, data.n_epochs, driver.core.period):
        moves = driver.controls.moves(policy.act(obs), n, driver.base_moves)
        made.append(moves)
        obs = driver.step_moves(moves).obs
    schedule = MoveSchedule.from_moves(driver.core.period, made)
    out = run_moves(cfg, data, schedule)
    out.diverged = out.diverged | driver.core.kf.diverged
    base = options.get("base")
    out.notes["policy"] = f"{describe}: controls {options['controls']}" + (
        f" on base {base}" if base else ""
    )
    return out


__all__ = ["check_policy", "run_policy"]
