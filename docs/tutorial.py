# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Tutorial: train a small policy and judge it
#
# This is a jupytext script: run it as it is (`.venv/bin/python docs/tutorial.py`), or open it
# as a notebook with jupytext. It does four things:
#
# 1. trains a small PPO policy on the scenario mixture;
# 2. judges it against `kf-tuned` and `glr` on two scenario families;
# 3. looks at the κ trace that the policy chose;
# 4. loads the results into pandas.
#
# The run is small, so the policy is weak. Scale `STEPS` and `TRIALS` up for a real
# judgement. `tests/test_tutorial.py` runs this file with tiny sizes
# (`QKF_TUTORIAL_SMALL=1`).
#
# The outputs go under `QKF_TUTORIAL_OUT` (default `results/tutorial`); that folder must be
# new or empty.

# %%
import os
from pathlib import Path

OUT = Path(os.environ.get("QKF_TUTORIAL_OUT", "results/tutorial"))
if OUT.exists() and any(OUT.iterdir()):  # before the imports below, which take seconds
    raise SystemExit(f"{OUT}: not empty; choose another QKF_TUTORIAL_OUT")

# %%
import matplotlib

matplotlib.use("Agg")  # files, not windows: the script also runs without a display
import matplotlib.pyplot as plt
import pandas as pd

from agents.config import load_train_config
from agents.training import train
from qkf.transfer_alignment.campaigns import run_study

SMALL = os.environ.get("QKF_TUTORIAL_SMALL") == "1"
STEPS = 1_024 if SMALL else 200_000  # environment steps of training
TRIALS = 2 if SMALL else 32  # judged trials per family
# shorter runs in the small version: 600 s instead of an hour, judged from 300 s on
SHORT = ["scenario.duration_s=600", "run.settled_s=300"] if SMALL else []
FAMILIES = ["steady_random", "thermal_snap_random"]

# %% [markdown]
# ## 1. Train
#
# `train_ppo_mixed_v3` is the training config of the zoo entry `ppo_mixed_v3`: PPO with an MLP
# over the last four observations of `qkf/TransferAlignment-v3`, on the `mixed_random`
# scenario family. Here it gets far fewer steps (the entry was trained for a million).

# %%
cfg = load_train_config(
    "train_ppo_mixed_v3",
    [f"total_steps={STEPS}", "n_envs=4", "eval={episodes: 1, seed: 100000, every_steps: 1024}"]
    + ([f"overrides={SHORT}"] if SMALL else []),
)
model = train(cfg, OUT / "policy", progress=not SMALL)
print("saved", model)

# %% [markdown]
# ## 2. Judge
#
# The families study runs every method on the same trials of each family, on a judging seed
# that no training or tuning used. `baselines` keeps two of the preset's baselines; the policy
# is added under the label `mine`.

# %%
run_study(
    "families",
    OUT / "families",
    progress=not SMALL,
    trials=TRIALS,
    sets=SHORT,
    families=FAMILIES,
    baselines=["kf-tuned", "glr"],
    extra_methods=[f"mine=policy:{model}"],
    seed=9000,
)
print((OUT / "families" / "families.md").read_text())

# %% [markdown]
# ## 3. The κ trace
#
# `kappa.csv` holds the κ of every method that varies it, per trial, every decision period.

# %%
kappa = pd.read_csv(OUT / "families" / "thermal_snap_random" / "kappa.csv")
mine = kappa[kappa.method == "mine"]
fig, ax = plt.subplots(figsize=(7, 3))
for trial, rows in mine.groupby("trial"):
    ax.step(rows.t_s, rows.kappa, where="post", label=f"trial {trial}")
ax.set(yscale="log", xlabel="t [s]", ylabel="κ", title="the policy's κ on thermal_snap_random")
ax.legend()
fig.savefig(OUT / "kappa_trace.png", dpi=100, bbox_inches="tight")

# %% [markdown]
# ## 4. The results in pandas
#
# `families.csv` has one row per family, method and metric: the value with its interval, and
# the ratio to `kf-tuned` with its paired interval. `trials.csv` of each family has the
# per-trial values that those come from.

# %%
families = pd.read_csv(OUT / "families" / "families.csv")
whole_state = families[families.metric == "state_settled"]
columns = ["family", "method", "value", "ratio_vs_kf_tuned", "ratio_lo", "ratio_hi"]
print(whole_state[columns].to_string(index=False))
trials = pd.read_csv(OUT / "families" / "thermal_snap_random" / "trials.csv")
per_trial = trials.pivot(index="trial", columns="method", values="state_settled")
print((per_trial["mine"] / per_trial["kf-tuned"]).describe())
