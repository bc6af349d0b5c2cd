"""Can the noise levels of ``gyro_noise_levels`` be identified online? (docs/redundant_gyros.md,
"Can the levels be identified online?")

Run: ``.venv/bin/python benchmarks/gyro_identifiability.py [--episodes 64]``.

For the episodes of environment seeds 5,000,000 on it compares, by Spearman rank correlation
over the episodes, the episode's best constant κ (the level-informed schedule's κ) and its
drawn drift and white-noise factors with what a causal estimator sees:

* the period means of the v3 observation's NIS and lag-1 innovation product, averaged over
  the first periods of a run at a fixed κ (what a single-filter policy observes);
* the v4 observation's ``log10 θ̂_R``, the VB estimate of the white noise's scale from the
  start (what ``vb-noise`` reads), after 1, 10, 30 periods and at the end;
* the κ of the action set with the largest innovation log-likelihood so far, from a bank of
  one filter per κ (multiple-model adaptive estimation), after 6, 11, 31 and 60 periods;

and the ``J`` (pooled RMS ratio and median per episode, to the best constant) of holding the
bank's maximum-likelihood κ chosen after 10 periods (scored over the whole episode, so a little
optimistic for the first 100 s).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from scipy import stats

from envs.redundant_gyros.episodes import GyroEpisodes
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.scenario import draw_onset, epochs, onset_generator
from qkf.redundant_gyros.ukf_compiled import SUMS

warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)
LOGLIK = SUMS.index("loglik")


def run_constant(cfg, seeds: np.ndarray, kappa: float, observation: str):  # type: ignore[no-untyped-def]
    """Every period's observations (T, N, size) and log-likelihood sums (T, N) at κ."""
    e = GyroEpisodes(seeds.size, cfg, reward="oracle", observation=observation)
    for i, s in enumerate(seeds):
        e.rngs[i] = np.random.default_rng(int(s))  # as a reset(seed=s)
    e.reset_envs(np.arange(seeds.size))
    obs, ll = [], []
    for _ in range(e.episode_steps):
        out = e.run(np.full(seeds.size, kappa), np.full(seeds.size, 0.5))
        obs.append(out.obs)
        ll.append(e.sums[:, LOGLIK].copy())
    return np.array(obs), np.array(ll)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="gyro_noise_levels")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--seed", type=int, default=5_000_000)
    args = ap.parse_args()
    cfg = load_config(args.config)
    spec = cfg.scenario.onset
    assert spec is not None, "a config with noise levels (scenario.onset)"
    seeds = args.seed + np.arange(args.episodes)
    kappas = np.asarray(cfg.environment.actions.values())
    const = np.stack([hs.constant_scores(hs.episode(cfg, int(s))) for s in seeds])
    best = np.log10(kappas[const.argmin(axis=1)])
    t = epochs(cfg.scenario.duration_s, cfg.scenario.dt_s)
    levels = np.array(
        [
            (d.drift_scale, d.noise_factor)
            for d in (draw_onset(spec, t, onset_generator(hs.env_draw(int(s)), 0)) for s in seeds)
        ]
    )

    def rho(a: np.ndarray, b: np.ndarray) -> float:
        return float(stats.spearmanr(a, b)[0])

    print(f"{args.config}, {args.episodes} episodes from seed {args.seed}")
    print(f"best log κ vs drift factor {rho(best, levels[:, 0]):+.2f}, "
          f"vs white-noise factor {rho(best, levels[:, 1]):+.2f}")  # fmt: skip
    print("| statistic | vs best log κ | vs drift | vs white noise |")
    print("|---|---|---|---|")
    kappa_mid = float(kappas[kappas.size * 2 // 3])
    obs, _ = run_constant(cfg, seeds, kappa_mid, "v3")
    for name, col in (("mean NIS", 4), ("mean lag-1 product", 5)):
        for lo, hi in ((1, 10), (1, 30), (10, obs.shape[0])):
            f = obs[lo:hi, :, col].mean(axis=0)
            print(f"| {name}, periods {lo}–{hi} at κ = {kappa_mid:.3g} | {rho(f, best):+.2f} | "
                  f"{rho(f, levels[:, 0]):+.2f} | {rho(f, levels[:, 1]):+.2f} |")  # fmt: skip
    obs4, _ = run_constant(cfg, seeds, kappa_mid, "v4")
    for after in (1, 10, 30, obs4.shape[0]):
        f = obs4[after - 1, :, 6]
        print(f"| VB log θ̂_R (v4) after {after} periods at κ = {kappa_mid:.3g} | "
              f"{rho(f, best):+.2f} | {rho(f, levels[:, 0]):+.2f} | "
              f"{rho(f, levels[:, 1]):+.2f} |")  # fmt: skip
    cum = np.stack([run_constant(cfg, seeds, float(k), "v2")[1] for k in kappas]).cumsum(axis=1)
    for after in (6, 11, 31, cum.shape[1]):
        khat = np.log10(kappas[cum[:, after - 1].argmax(axis=0)])
        print(f"| ML κ of the bank after {after} periods | {rho(khat, best):+.2f} | "
              f"{rho(khat, levels[:, 0]):+.2f} | {rho(khat, levels[:, 1]):+.2f} |")  # fmt: skip
    pick = cum[:, 9].argmax(axis=0)
    j = const[np.arange(seeds.size), pick]
    b = int(np.argmin(const.mean(axis=0)))
    print(f"hold the bank's ML κ from 100 s on ÷ best constant: pooled "
          f"{np.sqrt(j.sum() / const[:, b].sum()):.3f}, median per episode "
          f"{np.median(np.sqrt(j / const[:, b])):.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
