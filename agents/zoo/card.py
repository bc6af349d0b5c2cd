"""The model card of a zoo entry (``card.md``), written from the entry's own files: the spec,
the training config, each seed's records and the judging table. Rewritten by every
``qkf zoo train`` and ``qkf zoo evaluate``, so it never disagrees with the files beside it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from agents.config import TrainConfig
from agents.zoo.entry import ZooEntry
from agents.zoo.summary import LEVEL, read_summary
from envs import ENVIRONMENTS
from qkf.core.io import atomic_write_text

FAMILIES_SUMMARY = "zoo_families.csv"
JUDGING_SUMMARY = "zoo_judging.csv"


def _training_lines(entry: ZooEntry) -> list[str]:
    cfg = entry.train_cfg
    env = ENVIRONMENTS[cfg.env]
    reward = env.rewards[cfg.reward] if cfg.reward in env.rewards else None
    obs = env.observation or ""
    lines = [
        f"# {entry.name}",
        "",
        entry.spec.description,
        "",
        "## Training",
        "",
        f"- Command: `qkf zoo train {entry.name}` (each seed: `qkf train {entry.spec.train} "
        f"--seed S --out results/zoo/{entry.name}/seed_S`); deterministic by seed.",
        f"- Agent: {cfg.agent}, {_actions(cfg)}, environment `{cfg.env}`"
        + (f" (observation `{obs}`)" if obs else "")
        + f", decision period {cfg.period_s:g} s, {cfg.n_envs} parallel episodes.",
        f"- Scenario: `{cfg.scenario}`; training episodes from environment seeds "
        f"`seed … seed + {cfg.n_envs - 1}` and their generators; periodic evaluation on "
        f"environment seed {cfg.eval.seed} ({cfg.eval.episodes} episodes).",
        f"- Reward: `{cfg.reward}`"
        + (f": {reward.description}" if reward else "")
        + (
            " (uses the truth: simulation only; the observation never does)"
            if reward and reward.uses_truth
            else ""
        )
        + (f"; the learner sees it × {cfg.reward_scale:g}" if cfg.reward_scale != 1.0 else "")
        + ".",
        f"- Steps: {cfg.total_steps:,} per seed; hyperparameters: `{json.dumps(cfg.hyperparams)}`.",
        "",
        "| training seed | wall time [s] | cores | last evaluation return (env seed "
        f"{cfg.eval.seed}) | shipped |",
        "|---|---|---|---|---|",
    ]
    chosen = entry.selected_seed()
    for s in entry.spec.seeds:
        info_file = entry.seed_dir(s) / "training.json"
        info = json.loads(info_file.read_text()) if info_file.is_file() else {}
        score = entry.validation_score(s)
        shown = f"{score:.4g}" if np.isfinite(score) else "–"
        wall = str(info.get("wall_s", "–"))
        if info.get("resumed_from"):  # wall_s is the last session's only
            wall += f" (last session; resumed from {', '.join(info['resumed_from'])})"
        lines.append(
            f"| {s} | {wall} | {info.get('cpu_count', '–')} | "
            f"{shown} | {'yes' if s == chosen else ''} |"
        )
    lines += [
        "",
        "The shipped `model.*` is the seed with the best last evaluation on the environment "
        "evaluation seed, never on the judging seeds below.",
        "",
    ]
    return lines


def _fmt(r: dict[str, str]) -> str:
    value, lo, hi = (float(r[k]) for k in ("value", "lo", "hi"))
    return f"{value:.4g} [{lo:.4g}, {hi:.4g}]"


def _evaluation_lines(entry: ZooEntry, evaluation: Path) -> list[str]:
    path = evaluation / "zoo_summary.csv"
    if not path.is_file():
        if (evaluation / FAMILIES_SUMMARY).is_file() or (evaluation / JUDGING_SUMMARY).is_file():
            return []
        return ["## Evaluation", "", f"Not judged yet: `qkf zoo evaluate {entry.name}`.", ""]
    rows = read_summary(path)
    lines = [
        "## Evaluation",
        "",
        f"Command: `qkf zoo evaluate {entry.name}`. Benchmark seeds are disjoint from the "
        "environment seeds of training. Intervals: paired 95 % bootstrap over trials. Each "
        "cell: the pooled RMS ratio; then per trial the median ratio, the share of trials "
        "won and the worst decile (90th percentile of the per-trial ratios). `better` / "
        "`worse`: the pooled and the median intervals both below / above 1; `unjudged`: too "
        "few trials for a verdict. The IQM row is over training seeds, with the range of the "
        "seeds in brackets.",
        "",
    ]
    cases = dict.fromkeys((r["scenario"], r["seed"], r["trials"], r["metric"]) for r in rows)
    for scenario, seed, trials, metric in cases:
        sub = [
            r for r in rows if (r["scenario"], r["seed"], r["metric"]) == (scenario, seed, metric)
        ]
        versus = list(
            dict.fromkeys(r["versus"] for r in sub if r["quantity"] in ("ratio", "ratio_range"))
        )
        lines += [
            f"### {scenario} (benchmark seed {seed}, {trials} trials), `{metric}`",
            "",
            "| policy | RMS | "
            + " | ".join(f"÷ {v}" for v in versus)
            + " | share of kf→oracle gap |",
            "|---" * (3 + len(versus)) + "|",
        ]
        for policy in dict.fromkeys(r["policy"] for r in sub):
            mine = {(r["quantity"], r["versus"]): r for r in sub if r["policy"] == policy}
            rms = mine.get(("rms", ""))
            cells = [_fmt(rms) if rms else "–"]
            for v in versus:
                r = mine.get(("ratio", v)) or mine.get(("ratio_range", v))
                cell = _fmt(r) + (f" {r['verdict']}" if r and r["verdict"] else "") if r else "–"
                cells.append(cell + _per_trial_text(mine, v))
            g = mine.get(("gap_share", "kf→oracle")) or mine.get(("gap_share_range", "kf→oracle"))
            cells.append(_fmt(g) if g else "–")
            lines.append(f"| {policy} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def _num(text: str, digits: int = 3) -> str:
    value = float(text)
    return f"{value:.{digits}f}" if np.isfinite(value) else "–"


def _ratio_cell(r: dict[str, str]) -> str:
    """``value [lo, hi] verdict``, with more digits where three would print a decided bound
    as 1.000 (an interval that excludes 1 by less than 5e-4)."""
    digits = 3
    while (
        digits < 6
        and r["verdict"] in ("better", "worse")
        and "1." + "0" * digits in (_num(r["lo"], digits), _num(r["hi"], digits))
    ):
        digits += 1
    return (
        f"{_num(r['value'], digits)} [{_num(r['lo'], digits)}, {_num(r['hi'], digits)}] "
        f"{r['verdict']}"
    )


def _per_trial_text(mine: dict[tuple[str, str], dict[str, str]], versus: str) -> str:
    """``; median m [lo, hi], won w %, worst 10 % q`` of a comparison (empty without)."""
    med = mine.get(("median_ratio", versus))
    if med is None:
        return ""
    won = mine.get(("trials_won", versus))
    worst = mine.get(("worst_decile", versus))
    return (
        f"; median {_num(med['value'])} [{_num(med['lo'])}, {_num(med['hi'])}]"
        + (f", won {float(won['value']):.0%}" if won else "")
        + (f", worst 10 % {_num(worst['value'])}" if worst else "")
    )


def _families_lines(entry: ZooEntry, evaluation: Path) -> list[str]:
    """The families section of the card, from ``evaluation/zoo_families.csv``
    (:func:`agents.zoo.summary.families_summary`): per family the IQM line and a table of the
    baselines with the probability of improvement and the shipped seed's paired ratio."""
    path = evaluation / FAMILIES_SUMMARY
    if not path.is_file():
        return []
    rows = read_summary(path)
    if not rows:
        return []
    seed, pct = rows[0]["seed"], f"{100 * LEVEL:g} %"
    shipped = next((r["policy"] for r in rows if r["quantity"] == "ratio"), "")
    lines = [
        "## Scenario families",
        "",
        f"Command: `qkf zoo evaluate {entry.name}`: `qkf study families` (benchmark seed "
        f"{seed}, a judging seed) with the baselines and `{entry.name}#SEED=policy:"
        f"seed_SEED/{entry.model_name()}` of every training seed on the same trials; the "
        f"study's own tables are in `evaluation/families_seed{seed}.md`. Metric: "
        "`state_settled` (the settled RMS over the 15 states, each in units of its final "
        "nominal CRLB). Score per trial: RMS_kf-tuned / RMS_policy (above 1: better). IQM: "
        f"rliable's interquartile mean over training seeds × trials with its stratified "
        f"bootstrap {pct} interval. P(improve): the probability that the policy's score "
        "exceeds the baseline's on a trial (rliable; 0.5: no difference). Ratio: RMS of the "
        f"shipped seed's policy (`{shipped or '–'}`) ÷ the baseline's on the same trials, "
        f"paired {pct} bootstrap interval; per trial: the median ratio with its interval, the "
        "share of trials won and the worst decile (90th percentile of the per-trial ratios). "
        "`better` / `worse`: the pooled and the median intervals both below / above 1.",
        "",
    ]
    for family in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == family]
        iqm = next((r for r in mine if r["quantity"] == "iqm"), None)
        lines += [f"### {family} ({mine[0]['trials']} trials)", ""]
        if iqm is not None:
            lines += [
                f"IQM of RMS_kf-tuned / RMS_policy over seeds × trials: "
                f"{_num(iqm['value'])} [{_num(iqm['lo'])}, {_num(iqm['hi'])}] "
                f"({iqm['verdict']}).",
                "",
            ]
        p_improve = {r["versus"]: r for r in mine if r["quantity"] == "p_improve"}
        ratio = {r["versus"]: r for r in mine if r["quantity"] == "ratio"}
        per = {(r["quantity"], r["versus"]): r for r in mine}
        lines += [
            f"| baseline | P(improve) | {shipped or 'shipped seed'} ÷ baseline, pooled [{pct}] "
            "| median per trial | trials won | worst 10 % |",
            "|---|---|---|---|---|---|",
        ]
        for b in dict.fromkeys([*p_improve, *ratio]):
            p = p_improve.get(b)
            r = ratio.get(b)
            cell = _ratio_cell(r) if r else ""
            med, won, worst = (per.get((q, b)) for q in ("median_ratio", "trials_won",
                                                        "worst_decile"))  # fmt: skip
            med_cell = (
                f"{_num(med['value'])} [{_num(med['lo'])}, {_num(med['hi'])}]" if med else "–"
            )
            won_cell = f"{float(won['value']):.0%}" if won else "–"
            worst_cell = _num(worst["value"]) if worst else "–"
            lines.append(f"| {b} | {_num(p['value'], 2) if p else '–'} | {cell} | {med_cell} | "
                         f"{won_cell} | {worst_cell} |")  # fmt: skip
        lines.append("")
    return lines


def _judging_lines(entry: ZooEntry, evaluation: Path) -> list[str]:
    """The ``judging:`` section of the card, from ``evaluation/zoo_judging.csv``
    (:func:`agents.zoo.summary.judging_summary`): per family a table of every training seed's
    policy against every baseline, and the IQM over seeds."""
    path = evaluation / JUDGING_SUMMARY
    if not path.is_file():
        return []
    rows = read_summary(path)
    if not rows:
        return []
    seed, pct, metric = rows[0]["seed"], f"{100 * LEVEL:g} %", entry.problem.metric
    lines = [
        "## Judged on the problem's families",
        "",
        f"Command: `qkf zoo evaluate {entry.name}`: `qkf judge {entry.problem.name}` (benchmark "
        f"seed {seed}, a judging seed) with the baselines and `{entry.name}#SEED=policy:"
        f"seed_SEED/{entry.model_name()}` of every training seed on the same trials; the run's "
        f"own tables are in `evaluation/judging_seed{seed}_versus.md`. Metric: `{metric.name}` "
        f"({metric.description}). Cell: RMS of the policy ÷ the baseline's on the same trials, "
        f"paired {pct} bootstrap interval, verdict (`better` / `worse`: the pooled and the "
        "median per-trial intervals both below / above 1), then the median per-trial ratio and "
        "the share of trials won. IQM: the interquartile mean of the seeds' pooled ratios, with "
        "their range.",
        "",
    ]
    for family in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == family]
        bases = list(dict.fromkeys(r["versus"] for r in mine))
        cells = {(r["policy"], r["quantity"], r["versus"]): r for r in mine}
        lines += [
            f"### {family} ({mine[0]['trials']} trials)",
            "",
            "| policy | " + " | ".join(f"÷ {b}" for b in bases) + " |",
            "|---|" + "---|" * len(bases),
        ]
        for policy in dict.fromkeys(r["policy"] for r in mine):
            out = []
            for b in bases:
                r = cells.get((policy, "ratio", b))
                span = cells.get((policy, "ratio_range", b))
                med, won = (
                    cells.get((policy, "median_ratio", b)),
                    cells.get((policy, "trials_won", b)),
                )
                if r is not None:
                    text = _ratio_cell(r)
                    if med is not None and won is not None:
                        text += f"; median {_num(med['value'])}, won {float(won['value']):.0%}"
                elif span is not None:
                    text = f"{_num(span['value'])} ({_num(span['lo'])}–{_num(span['hi'])})"
                else:
                    text = "–"
                out.append(text)
            lines.append(f"| {policy} | " + " | ".join(out) + " |")
        lines.append("")
    return lines


def write_card(entry: ZooEntry, folder: Path | None = None) -> Path:
    """Write ``card.md`` into ``folder`` (default: the entry's own), its judging tables from
    ``folder/evaluation/`` (``zoo_summary.csv``, ``zoo_families.csv``); returns its path."""
    folder = entry.folder if folder is None else folder
    evaluation = folder / "evaluation"
    lines = (
        _training_lines(entry)
        + _evaluation_lines(entry, evaluation)
        + _families_lines(entry, evaluation)
        + _judging_lines(entry, evaluation)
    )
    path = folder / "card.md"
    atomic_write_text(path, "\n".join(lines).rstrip() + "\n")
    return path


def _actions(cfg: TrainConfig) -> str:
    """What the agent's actions are: κ, or the moves of v4's controls (on a residual base)."""
    controls = cfg.env_kwargs.get("controls")
    if controls is None:
        return f"{cfg.action_type} κ actions"
    base = cfg.env_kwargs.get("base")
    return f"{cfg.action_type} actions of the controls `{controls}`" + (
        f" correcting the rule `{base}`" if base else ""
    )
