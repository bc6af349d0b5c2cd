"""Fixed-Q filters: the nominal one (κ = 1) and the oracle-tuned constant κ (SPEC §3)."""

from __future__ import annotations

import numpy as np

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput, action_values, new_filter
from qkf.transfer_alignment.metrics import state_errors
from qkf.transfer_alignment.scenario import ScenarioData, simulate


def run_fixed(cfg: Config, data: ScenarioData, kappa: float) -> MethodOutput:
    """The transfer-alignment KF with a constant process-noise factor ``κ``."""
    kf = new_filter(cfg, data)
    rec = kf.step_data(data, 0, data.n_epochs, kappa=kappa)
    return MethodOutput(est=rec.est, diverged=kf.diverged.copy())


def run_kf(cfg: Config, data: ScenarioData) -> MethodOutput:
    """Fixed-Q KF: κ = ``run.kappa`` (1 by default)."""
    return run_fixed(cfg, data, cfg.run.kappa)


_TUNED: dict[str, tuple[float, tuple[float, ...]]] = {}


def tuned_kappa(cfg: Config) -> tuple[float, tuple[float, ...]]:
    """The action whose constant κ gives the lowest time-averaged calibration RMS on the
    tuning trials (seed ``adaptive.tuned.seed``, disjoint from any evaluation seed's streams).

    Returns ``(κ*, calibration RMS per action)``; the RMS is over trials, epochs and the nine
    calibration terms, in 1e-6 (ppm or µrad).
    """
    key = cfg.model_dump_json()
    if key in _TUNED:  # one tuning per config and process, whatever the number of chunks
        return _TUNED[key]
    tc = cfg.adaptive.tuned
    data = simulate(cfg, tc.seed, tc.trials)
    kappas = action_values(cfg)
    scores = []
    for kappa in kappas:
        out = run_fixed(cfg, data, float(kappa))
        err = state_errors(out.est, data.q_true, data.bias, data.calib)[..., 6:15]
        scores.append(float(np.sqrt(np.mean(err**2))) / 1e-6)
    best = int(np.nanargmin(scores))
    _TUNED[key] = (float(kappas[best]), tuple(scores))
    return _TUNED[key]


def run_kf_tuned(cfg: Config, data: ScenarioData) -> MethodOutput:
    """Tuned fixed-Q KF: the best constant κ of the action set, picked on tuning seeds."""
    kappa, _ = tuned_kappa(cfg)
    out = run_fixed(cfg, data, kappa)
    n = cfg.adaptive.tuned.trials
    out.notes["kf-tuned"] = f"κ = {kappa:.3g} (best constant κ on {n} tuning trials)"
    return out
