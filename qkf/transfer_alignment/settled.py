r"""Each trial's settled window and state weights: where, and in what units, a method is judged
(docs/methods.md, "The settled window").

A trial's settled window opens at::

    t_open = max( run.settled_s,  first t ≥ t_exc  with  bound_i(t) ≤ f · bound_i(T)  for every
                                                          calibration term i )

``t_exc`` is the end of the trial's *opening excitation*: its rotation sequence that starts
first, with the rotations that follow it back to back (:func:`opening_end_s`). ``bound`` is the
CRLB of the trial's *own* trajectory (its rotations, jumps, drift segment and true ADS noise,
:func:`~qkf.transfer_alignment.crlb.crlb`), ``T`` its last epoch and ``f`` =
``run.settle_factor`` (2). The window runs to the end of the run.

The weights of ``state_settled`` are the same trajectory's bound at ``T`` (15,), so a trial is
scored in units of what *it* can be known to, not what the nominal schedule could.

Why the window cannot hold the convergence transient: before the opening excitation has ended
the calibration is not observable, and its error is prior-limited (1,500 ppm against a final
bound below 1 ppm: ~10³ in the metric's units). From ``t_open`` on an efficient estimator's
calibration error is within ``f`` × the weight it is scored in, whenever the trial's rotations
end; a fixed ``run.settled_s`` holds the transient of every trial whose rotations end after it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from qkf.transfer_alignment.config import Config, Maneuver, Scenario
from qkf.transfer_alignment.crlb import crlb
from qkf.transfer_alignment.model import CALIB
from qkf.transfer_alignment.scenario import ScenarioData, draw_events, trial_streams


@dataclass(frozen=True)
class SettledWindows:
    """Per trial (rows of a :class:`~qkf.transfer_alignment.scenario.ScenarioData`): the index
    of the first settled epoch (B,) and the weights of ``state_settled`` (B, 15), SI."""

    first: np.ndarray  # (B,) int64
    weights: np.ndarray  # (B, 15)

    def mask(self, n_epochs: int) -> np.ndarray:
        """Settled epochs per trial (B, N) bool: a suffix of the run."""
        return np.arange(n_epochs)[None, :] >= self.first[:, None]


def opening_end_s(maneuvers: list[Maneuver]) -> float:
    """End of the opening excitation, s: the rotation that starts first and every rotation
    that starts before (or as) the previous ones end; 0 without rotations."""
    end = 0.0
    for m in sorted(maneuvers, key=lambda m: m.start_s):
        if end > 0.0 and m.start_s > end + 1e-9:
            break
        end = max(end, m.start_s + m.duration_s)
    return end


def trial_scenario(cfg: Config, seed: int, trial: int) -> Scenario:
    """The scenario trial ``trial`` of seed ``seed`` was simulated with (its drawn events;
    ``cfg.scenario`` itself when nothing is drawn)."""
    return draw_events(cfg.scenario, trial_streams(seed, trial)["events"])


def settled_windows(
    cfg: Config, data: ScenarioData, weights: np.ndarray | None = None
) -> SettledWindows:
    """The settled windows and weights of ``data``'s trials, simulated from ``cfg`` (module
    docstring). ``weights`` (15,) SI: data that are not a simulation of ``cfg`` (recorded
    runs), judged from ``run.settled_s`` in these fixed units."""
    b, t = data.n_trials, data.t
    if weights is not None:
        first = np.full(b, _index(t, cfg.run.settled_s), dtype=np.int64)
        return SettledWindows(first, np.broadcast_to(weights, (b, 15)).copy())
    if cfg.scenario.random_events is None:
        open_s, w = _window(_key(cfg, cfg.scenario))
        first = np.full(b, _index(t, open_s), dtype=np.int64)
        return SettledWindows(first, np.broadcast_to(w, (b, 15)).copy())
    first = np.empty(b, dtype=np.int64)
    out = np.empty((b, 15))
    for row, trial in enumerate(data.trial_ids.tolist()):
        open_s, out[row] = _window(_key(cfg, trial_scenario(cfg, data.seed, int(trial))))
        first[row] = _index(t, open_s)
    return SettledWindows(first, out)


def _index(t: np.ndarray, open_s: float) -> int:
    """The first epoch at ``t ≥ open_s``; the last epoch for a run that ends before it (a
    window is never empty)."""
    return min(int(np.searchsorted(t, open_s - 1e-9)), t.size - 1)


def _key(cfg: Config, scenario: Scenario) -> str:
    # what the window depends on: the trial's scenario, the filter (matching, prior) and the
    # two run settings; nothing else, so trials with equal draws share one CRLB run
    run = type(cfg.run)(settled_s=cfg.run.settled_s, settle_factor=cfg.run.settle_factor)
    key = cfg.model_copy(
        update={"scenario": scenario, "adaptive": type(cfg.adaptive)(), "run": run}
    )
    return key.model_dump_json()


@lru_cache(maxsize=4096)
def _window(cfg_json: str) -> tuple[float, np.ndarray]:
    cfg = Config.model_validate_json(cfg_json)
    bound = crlb(cfg)
    final = bound.bound[-1]
    if not np.all(np.isfinite(final) & (final > 0.0)):
        raise ValueError("the CRLB at the end of the run is not finite and positive")
    t = bound.t
    start = _index(t, opening_end_s(cfg.scenario.maneuvers))
    within = np.all(bound.bound[:, CALIB] <= cfg.run.settle_factor * final[CALIB], axis=1)
    within[:start] = False
    converged = float(t[np.flatnonzero(within)[0]]) if within.any() else float(t[-1])
    final.setflags(write=False)
    return max(cfg.run.settled_s, converged), final
