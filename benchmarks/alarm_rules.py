"""Hand-written alarm rules against the oracle: how much of the kf → oracle gap a detector
closes, and why the environment's observation v2 carries the age of the current change.

Run: ``.venv/bin/python benchmarks/alarm_rules.py [--scenario thermal_snap_random]
[--seed 7000] [--trials 32]``.

The oracle schedule (``κ_after`` for ``W`` seconds from each trial's true jump, ``κ_base``
elsewhere) is tuned with the truth on the tuning seeds, as in ``qkf bench``. Two rules replace
the true jump time by what the filter sees, with the oracle's own (κ_base, κ_after, W):

* ``every alarm``: κ_after for W after each alarm (v1 entry 7 at 0: a period with mean NIS
  per row > 4), run through the environment's v1 observation;
* ``alarm-burst``: κ_after while the age of the current change is below W (the method of that
  name; the same age is v2 entry 12).

All run on the same trials (paired); the table gives the settled misalignment RMS, paired 95 %
bootstrap intervals of the ratio to ``kf`` and to the constant κ_base, and the share of the
kf → oracle gap closed (docs/environment.md, "Observation v2").
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from envs.transfer_alignment.episodes import BatchedEpisodes
from qkf.core.stats import bootstrap_rms, percentile_interval, resample_counts
from qkf.transfer_alignment.config import Config, load_config
from qkf.transfer_alignment.methods.alarm_burst import AlarmBurstSchedule
from qkf.transfer_alignment.methods.fixed import run_fixed
from qkf.transfer_alignment.methods.oracle import tune_oracle
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, state_errors, trial_mean_squares
from qkf.transfer_alignment.scenario import ScenarioData, simulate
from qkf.transfer_alignment.settled import settled_windows

Rule = Callable[[np.ndarray], np.ndarray]  # observation (B, size) → κ (B,)


def settled_ms(cfg: Config, data: ScenarioData, est: np.ndarray) -> np.ndarray:
    """Per-trial settled mean square of the misalignment error, µrad² (B,)."""
    err = state_errors(est, data.q_true, data.bias, data.calib)
    first = settled_windows(cfg, data).first
    ms = trial_mean_squares(err, data.t, first, np.ones(err.shape[-1]))
    return ms[:, METRIC_COLUMNS.index("ma_urad_settled")] / 1e-12


def run_rule(cfg: Config, data: ScenarioData, observation: str, rule: Rule) -> np.ndarray:
    """Filter every trial with κ chosen each decision period by ``rule``; settled MS (B,).
    (The reward is not used; ``oracle`` is the cheapest to compute.)"""
    core = BatchedEpisodes(cfg, data.n_trials, "oracle", 10.0, observation=observation)
    obs = core.load(data)
    est = np.full((data.n_trials, data.n_epochs, 16), np.nan)
    for k0 in range(0, data.n_epochs, core.period):
        out = core.step(rule(obs), np.zeros(data.n_trials))
        est[:, k0 : k0 + core.period] = out.est
        obs = out.obs
    return settled_ms(cfg, data, est)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scenario", default="thermal_snap_random")
    ap.add_argument("--seed", type=int, default=7000)
    ap.add_argument("--trials", type=int, default=32)
    args = ap.parse_args()
    cfg = load_config(args.scenario, ["adaptive.oracle.metric=ma_urad_settled"])
    data = simulate(cfg, args.seed, args.trials)
    orc = tune_oracle(cfg)
    base, after, window = orc.base, orc.after, orc.window_s
    print(f"oracle (tuned with the truth): κ = {after:.3g} for {window:g} s, else {base:.3g}")
    n = data.n_trials
    ms = {
        "kf (κ = 1)": settled_ms(cfg, data, run_fixed(cfg, data, 1.0).est),
        f"constant κ_base = {base:.3g}": settled_ms(cfg, data, run_fixed(cfg, data, base).est),
        "every alarm": run_rule(
            cfg, data, "v1", _hold(lambda o: o[:, 7] == 0.0, after, base, window)
        ),
        "alarm-burst (first alarm of a change)": settled_ms(
            cfg, data, AlarmBurstSchedule(orc)(cfg, data).est
        ),
        "oracle": settled_ms(cfg, data, orc(cfg, data).est),
    }
    counts = resample_counts(n, 2000, args.seed)
    boot = {k: bootstrap_rms(v, counts) for k, v in ms.items()}
    rms = {k: float(np.sqrt(v.mean())) for k, v in ms.items()}
    kf, cst, orc_name = "kf (κ = 1)", f"constant κ_base = {base:.3g}", "oracle"
    print(f"{cfg.name}: {n} trials of seed {args.seed}, settled misalignment RMS (µrad)")
    print(f"{'':38s} {'RMS':>7s}  {'ratio to kf [95 %]':>24s}  {'to κ_base [95 %]':>24s}  gap")
    for k in ms:
        cells = []
        for ref in (kf, cst):
            lo, hi = percentile_interval(boot[k] / boot[ref])
            cells.append(f"{rms[k] / rms[ref]:.4f} [{float(lo):.4f}, {float(hi):.4f}]")
        share = (rms[kf] - rms[k]) / (rms[kf] - rms[orc_name])
        print(f"{k:38s} {rms[k]:7.2f}  {cells[0]:>24s}  {cells[1]:>24s}  {share:5.2f}")


def _hold(trigger: Rule, after: float, base: float, window: float) -> Rule:
    """κ_after for ``window`` seconds after every period where ``trigger`` fires."""
    state: dict[str, np.ndarray] = {}

    def rule(obs: np.ndarray) -> np.ndarray:
        left = state.get("left", np.zeros(obs.shape[0]))
        left = np.where(trigger(obs), window, left - 10.0)
        state["left"] = left
        return np.where(left > 0.0, after, base)

    return rule


if __name__ == "__main__":
    main()
