"""Transfer alignment as a :class:`~qkf.core.problem.Problem`: what the experiments layer (the
zoo, policy evaluation, the families judging) needs of it, without importing its modules.

The families live here, the facts sheet of the problem; the methods, the simulation and the
workload check are imported on first use, so that reading the problem stays cheap.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.problem import Families, JudgedMetric, SeedRanges, TrialRequest
from qkf.core.registry import Imported
from qkf.transfer_alignment.adaptive import MAX_TRIALS, TUNING_SEEDS
from qkf.transfer_alignment.problem_studies import BENCH, FAMILIES_STUDY_RUNNER

FAMILIES: tuple[str, ...] = (
    "steady_random",
    "thermal_snap_random",
    "double_snap_random",
    "small_snap_random",
    "early_snap_random",
    "thermal_drift_random",
    "ads_mismatch_random",
    "rotation_only_random",
    "quiet_snap_random",
    "threshold_snap_random",
    "mixed_random",
)
"""The training families (presets of configs/transfer_alignment/), in table order: the ten
that ``mixed_random`` draws from, then the mixture itself."""

SHIFT_FAMILIES: tuple[str, ...] = (
    "shift_late_snap_random",
    "shift_ads_noise_random",
    "shift_rotations_random",
    "shift_prior_random",
)
"""The shift group (docs/models.md, "Shift group"): each changes the law of one thing a
training family draws (jump times, ADS noise, rotation rates and durations, the calibration
prior). Nothing trains or tunes on them: never in a training mixture, never a tuning run's
scenario (``tests/test_shift_group.py``); ``qkf study families --shift`` judges them, the zoo's
evaluation always does."""

ENV_IDS: tuple[str, ...] = (
    "qkf/TransferAlignment-v0",
    "qkf/TransferAlignment-v1",
    "qkf/TransferAlignment-v2",
    "qkf/TransferAlignment-v3",
    "qkf/TransferAlignmentTimed-v3",
    "qkf/TransferAlignment-v4",
)
"""The environments of this problem (``envs.transfer_alignment`` registers them)."""


class TransferAlignment:
    """The transfer-alignment problem (docs/models.md)."""

    name = "transfer_alignment"
    description = "in-orbit calibration of gyros against a master's attitude reference"
    env_ids = ENV_IDS
    families = Families(
        judged=FAMILIES,
        control=("steady_random",),
        shift=SHIFT_FAMILIES,
        mixture="mixed_random",
        shift_tuned_on="mixed_random",
    )
    metric = JudgedMetric(
        "state_settled",
        "the whole state's settled error, each state in units of its final nominal CRLB "
        "(dimensionless)",
    )
    # docs/environment.md, "Seed ranges": judging below the tuning seeds
    seeds = SeedRanges(judging=(0, TUNING_SEEDS[0]), tuning=TUNING_SEEDS)
    max_trials = MAX_TRIALS
    bench = BENCH  # qkf bench: qkf evaluate, a zoo entry's judge: cases
    families_study = FAMILIES_STUDY_RUNNER  # qkf study families: a zoo entry's families:

    methods = Imported("qkf.transfer_alignment.methods:METHODS")

    def load_config(self, source: str | Path | None, overrides: Sequence[str] = ()) -> Any:
        """:func:`qkf.transfer_alignment.config.load_config`."""
        from qkf.transfer_alignment.config import load_config

        return load_config(source, list(overrides))

    def simulate(self, cfg: Any, seed: int, trials: Sequence[int]) -> Any:
        """:func:`qkf.transfer_alignment.scenario.simulate`: a ``ScenarioData``."""
        from qkf.transfer_alignment.scenario import simulate

        return simulate(cfg, seed, list(trials))

    def check_workload(self, cfg: Any, trials: int) -> None:
        """:func:`qkf.transfer_alignment.config.check_workload`."""
        from qkf.transfer_alignment.config import check_workload

        check_workload(cfg, trials)

    def method_labels(self, specs: Sequence[str]) -> list[str]:
        """:func:`~qkf.transfer_alignment.benchmark.parse_methods`' names."""
        from qkf.transfer_alignment.benchmark import parse_methods

        return [m.name for m in parse_methods(list(specs))]

    def check_methods(self, cfg: Any, specs: Sequence[str]) -> None:
        """The methods' settings sections and each method's ``check(cfg)`` (``policy:PATH``: its
        action set): :func:`~qkf.transfer_alignment.methods.resolve_method_settings`."""
        from qkf.transfer_alignment.benchmark import parse_methods
        from qkf.transfer_alignment.methods import resolve_method_settings

        resolve_method_settings(cfg, parse_methods(list(specs)))

    def trial_errors(self, cfg: Any, request: TrialRequest) -> dict[str, np.ndarray]:
        """``state_settled`` per trial of each method of a
        :func:`~qkf.transfer_alignment.benchmark.run_benchmark` run. With
        ``request.tuning_cfg`` (a shift family: the training mixture,
        ``Families.shift_tuned_on``) every method that tunes on the judged config (it has a
        ``prepare``) tunes on that config's scenario instead, as its ``-mixed`` twin does
        (:class:`~.methods.on_mixture.TunedOnScenario`); the ``-mixed`` twins themselves are
        unchanged. ``request.cache``: the bench's results cache, per chunk of trials and per
        tuning (a damaged entry: a ``CacheWarning``)."""
        from qkf.transfer_alignment.benchmark import parse_methods, run_benchmark
        from qkf.transfer_alignment.methods import NamedMethod
        from qkf.transfer_alignment.methods.on_mixture import TunedOnMixture, TunedOnScenario
        from qkf.transfer_alignment.metrics import METRIC_COLUMNS

        named = parse_methods(list(request.specs))
        tuning_cfg, cache = request.tuning_cfg, request.cache
        if tuning_cfg is not None:
            named = [
                NamedMethod(
                    m.name, TunedOnScenario(m.method, tuning_cfg.scenario, tuning_cfg.name), m.spec
                )
                if callable(getattr(m.method, "prepare", None))
                and not isinstance(m.method, TunedOnMixture)
                else m
                for m in named
            ]

        res = run_benchmark(
            cfg, named, request.trials, request.seed, request.progress, cache=cache is not None
        )
        if cache is not None:  # per method: chunks found, computed, damaged; its tuning's
            cache.problems.extend(res.cache_problems)
            for label, counts in res.cache.items():
                for status, times in counts.items():
                    cache.add(label, status, times)
        j = METRIC_COLUMNS.index(self.metric.name)
        return {m.name: np.asarray(m.trial_values)[:, j] for m in res.methods}


PROBLEM = TransferAlignment()
"""Registered as ``transfer_alignment`` in :data:`qkf.core.problem.PROBLEMS`."""

__all__ = ["ENV_IDS", "FAMILIES", "PROBLEM", "SHIFT_FAMILIES", "TransferAlignment"]
