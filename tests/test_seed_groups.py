"""qkf.core.seed_groups: the training seeds of a policy pooled (rliable's IQM of the normalised
score over seeds × trials, the probability of improvement), checked by hand on made-up errors
of known scores, for any problem's judged error."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from qkf.core.seed_groups import SEED_MARK, seed_groups, seed_statistics


def _errors(rng: np.random.Generator, trials: int = 12) -> dict[str, np.ndarray]:
    ref = rng.uniform(1.0, 2.0, trials)
    return {
        "ref": ref,
        "other": ref * rng.uniform(0.8, 1.3, trials),
        "p#0": ref / rng.uniform(0.7, 1.5, trials),
        "p#1": ref / rng.uniform(0.7, 1.5, trials),
        "p#2": ref.copy(),  # scores exactly 1: ties with the reference
        "q#5": ref / 2.0,
    }


def test_seed_groups_collect_the_labels_of_each_policy() -> None:
    assert seed_groups(["kf", "p#0", "q#3", "p#1"]) == {"p": ["p#0", "p#1"], "q": ["q#3"]}
    assert seed_groups(["kf", "glr"]) == {}
    assert SEED_MARK == "#"


def test_iqm_and_probability_of_improvement_by_hand() -> None:
    errors = _errors(np.random.default_rng(4))
    stats = seed_statistics(errors, ["ref", "other", "q#5"], "ref", 0.9, reps=300, seed=1)
    by = {str(s["policy"]): s for s in stats}
    assert sorted(by) == ["p", "q"] and by["p"]["seeds"] == 3 and by["q"]["seeds"] == 1
    ref = errors["ref"]
    scores = np.stack([ref / errors[f"p#{k}"] for k in range(3)])  # (seeds, trials)
    assert by["p"]["iqm"] == pytest.approx(sps.trim_mean(scores.ravel(), 0.25), rel=1e-12)
    assert by["p"]["iqm_lo"] <= by["p"]["iqm"] <= by["p"]["iqm_hi"]
    assert by["q"]["iqm"] == pytest.approx(2.0, rel=1e-12)  # every score 2: no spread
    assert by["q"]["iqm_lo"] == pytest.approx(2.0) and by["q"]["iqm_hi"] == pytest.approx(2.0)
    # rliable's probability of improvement: per trial, the share of (policy run, baseline)
    # pairs where the policy scores higher (ties half), averaged over trials
    other = ref / errors["other"]
    per_trial = [np.mean((scores[:, k] > other[k]) + 0.5 * (scores[:, k] == other[k]))
                 for k in range(ref.size)]  # fmt: skip
    assert by["p"]["p_improve_other"] == pytest.approx(float(np.mean(per_trial)), rel=1e-12)
    ones = [np.mean((scores[:, k] > 1.0) + 0.5 * (scores[:, k] == 1.0)) for k in range(ref.size)]
    assert by["p"]["p_improve_ref"] == pytest.approx(float(np.mean(ones)), rel=1e-12)
    # a seeded label is a policy, never a baseline
    assert "p_improve_q#5" not in by["p"]


def test_same_inputs_same_numbers_and_nothing_without_the_reference() -> None:
    errors = _errors(np.random.default_rng(7))
    a = seed_statistics(errors, ["other"], "ref", 0.95, reps=200, seed=3)
    np.random.seed(12345)  # noqa: NPY002 (what ran before in the process must not matter)
    outside = np.random.get_state()[1].copy()  # noqa: NPY002
    b = seed_statistics(errors, ["other"], "ref", 0.95, reps=200, seed=3)
    assert a == b
    assert np.array_equal(np.random.get_state()[1], outside)  # noqa: NPY002 (restored)
    c = seed_statistics(errors, ["other"], "ref", 0.95, reps=200, seed=4)
    assert [r["iqm"] for r in c] == [r["iqm"] for r in a]  # the point estimate has no draw
    assert [(r["iqm_lo"], r["iqm_hi"]) for r in c] != [(r["iqm_lo"], r["iqm_hi"]) for r in a]
    assert seed_statistics(errors, ["other"], "missing", 0.95) == []
    assert seed_statistics({"ref": errors["ref"], "other": errors["other"]}, [], "ref", 0.95) == []
