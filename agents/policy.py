"""A saved agent (``qkf train``) as a benchmark method: ``--methods policy:PATH``.

The policy sees the environment's observation (``envs.episodes``) every decision period and its
action sets κ for the next period; everything else is the filter of every other method, run
on the same simulated trials.
"""

from __future__ import annotations

import numpy as np

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput
from qkf.transfer_alignment.scenario import ScenarioData

PREFIX = "policy:"


def run_policy(cfg: Config, data: ScenarioData, path: str) -> MethodOutput:
    """Filter the trials with κ chosen by the saved policy at ``path``."""
    from agents.training import Policy
    from envs.episodes import BatchedEpisodes
    from envs.transfer_alignment import ActionMap

    policy = Policy(path)
    actions = ActionMap(np.asarray(cfg.adaptive.actions.values()), policy.cfg.action_type)
    core = BatchedEpisodes(cfg, data.n_trials, "likelihood")
    obs = core.load(data)
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
    kappas = np.asarray(cfg.adaptive.actions.values())
    idx = np.abs(np.log(np.stack(kappa_log, axis=1))[..., None] - np.log(kappas)).argmin(axis=-1)
    return MethodOutput(
        est=est,
        diverged=core.kf.diverged.copy(),
        extras={"kappa_index": idx} if policy.cfg.action_type == "discrete" else {},
        notes={"policy": f"{policy.cfg.agent} policy from {path}"},
    )
