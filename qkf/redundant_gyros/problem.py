"""The redundant-gyro calibration episodes as a :class:`~qkf.core.problem.Problem`: what the
experiments layer (judging κ policies and methods over the gyro families) needs of it.

A trial is one episode of the gyro environments: trial ``t`` of benchmark seed ``s`` is the
episode of ``env.reset(seed=s + t)`` (:func:`~.hindsight.episode`), so a policy run in the
environment and a method run here see the same readings. Its judged error is ``√J``
(:mod:`.methods`). Judging seeds start at 5,000,000, beyond the seeds the training configs draw
their episodes from and the tuning seeds; the tuned methods tune on the first
:data:`TUNING_EPISODES` episodes of the tuning range.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.config import ConfigError
from qkf.core.problem import Families, JudgedMetric, SeedRanges, TrialRequest
from qkf.core.registry import Imported
from qkf.core.results_cache import CacheLog
from qkf.redundant_gyros.config import MAX_CHUNK_TRIAL_EPOCHS, MAX_TRIALS, epochs_of

FAMILIES: tuple[str, ...] = ("gyro_noise_levels", "five_gyros_onset_drift", "gyro_mixture")
"""The gyro families with a change (presets of configs/redundant_gyros/; docs/redundant_gyros.md,
"Gyro families"), the last the training mixture of the others and the control."""
MIXTURE = "gyro_mixture"
"""Each episode one of the noise levels, the onset and drift, or the control, drawn uniformly."""
CONTROL_FAMILIES: tuple[str, ...] = ("gyro_control",)
"""Nothing changes: constant coefficients, the assumed noise."""
SHIFT_FAMILIES: tuple[str, ...] = ("gyro_shift_noise_levels",)
"""Never trained or tuned on: noise levels beyond the training family's. Judged there, the
tuned methods tune on ``gyro_noise_levels``' tuning episodes (``Families.shift_tuned_on``)."""

ENV_IDS: tuple[str, ...] = (
    "qkf/RedundantGyroCalibration-v0",
    "qkf/RedundantGyroCalibration-v1",
    "qkf/RedundantGyroCalibration-v2",
    "qkf/RedundantGyroCalibration-v3",
    "qkf/RedundantGyroCalibration-v4",
)
"""The environments of this problem (``envs.redundant_gyros`` registers them)."""

TUNING_EPISODES = 16
"""Episodes the tuned methods tune on (the first of the tuning seeds; every tuned method the
same)."""


class RedundantGyros:
    """The gyro calibration episodes (docs/redundant_gyros.md)."""

    name = "redundant_gyros"
    description = "κ of the UKF calibrating one of a redundant, skewed gyro unit's gyros"
    env_ids = ENV_IDS
    families = Families(
        judged=FAMILIES,
        control=CONTROL_FAMILIES,
        shift=SHIFT_FAMILIES,
        mixture=MIXTURE,
        shift_tuned_on="gyro_noise_levels",
    )
    metric = JudgedMetric(
        "rms_settled",
        "√J: the settled RMS of the four calibrated states over their prior sd (dimensionless)",
    )
    seeds = SeedRanges(
        judging=(5_000_000, 6_000_000), tuning=(1_000_000, 2_000_000), seed_per_trial=True
    )
    max_trials = MAX_TRIALS
    bench = None  # its benches are qkf gyros bench's; a zoo entry is judged by qkf judge
    families_study = None

    methods = Imported("qkf.redundant_gyros.methods:GYRO_METHODS")

    def load_config(self, source: str | Path | None, overrides: Sequence[str] = ()) -> Any:
        """:func:`qkf.redundant_gyros.load_config`."""
        from qkf.redundant_gyros import load_config

        return load_config(source, list(overrides))

    def simulate(self, cfg: Any, seed: int, trials: Sequence[int]) -> Any:
        """The episodes (:class:`~.hindsight.Episode`) of environment seeds ``seed + t``."""
        from qkf.redundant_gyros.hindsight import episode

        return [episode(cfg, seed + int(t)) for t in trials]

    def tuning(self, cfg: Any) -> Any:
        """The episodes the tuned methods tune on."""
        return self.simulate(cfg, self.seeds.tuning[0], range(TUNING_EPISODES))

    def check_workload(self, cfg: Any, trials: int) -> None:
        """``ConfigError`` if ``trials`` episodes, all held at once, exceed
        :data:`~.config.MAX_CHUNK_TRIAL_EPOCHS` trial-epochs."""
        from qkf.redundant_gyros.hindsight import SETTLED_S

        if cfg.scenario.duration_s <= SETTLED_S:
            raise ConfigError(
                f"scenario.duration_s: {cfg.scenario.duration_s:g} s leaves no judged epoch "
                f"(episodes are judged from {SETTLED_S:g} s on)"
            )
        epochs = epochs_of(cfg.scenario.duration_s, cfg.scenario.dt_s)
        if trials * epochs > MAX_CHUNK_TRIAL_EPOCHS:
            raise ConfigError(
                f"trials × epochs (scenario.duration_s / scenario.dt_s) = {trials:,} × "
                f"{epochs:,} = {trials * epochs:.3g} trial-epochs, all held at once; at most "
                f"{MAX_CHUNK_TRIAL_EPOCHS:.0e}: judge {MAX_CHUNK_TRIAL_EPOCHS // epochs:,} "
                "trials or fewer"
            )

    def method_labels(self, specs: Sequence[str]) -> list[str]:
        """The labels of :func:`~qkf.redundant_gyros.methods.resolve_gyro_method`."""
        return [label for label, _ in _resolved(specs)]

    def check_methods(self, cfg: Any, specs: Sequence[str]) -> None:
        """Each method's ``check(cfg)``, where it has one (``policy:PATH``: its action set)."""
        for _, method in _resolved(specs):
            check = getattr(method, "check", None)
            if callable(check):
                check(cfg)

    def trial_errors(self, cfg: Any, request: TrialRequest) -> dict[str, np.ndarray]:
        """``√J`` per episode of each method (:mod:`qkf.redundant_gyros.methods`), the tuned
        ones tuned on :meth:`tuning`'s episodes of ``request.tuning_cfg`` (None: ``cfg``).
        ``request.cache``: each method's ``J`` per episode is read from the results cache when
        stored under :func:`results_key` and stored there when computed (a method that cannot
        be described: ``off``); the episodes are simulated only if some method is computed."""
        from qkf.core.montecarlo import progress_bar
        from qkf.core.results_cache import Entry, ResultsCache

        methods = _resolved(request.specs)
        seed, trials, cache = request.seed, request.trials, request.cache
        store = ResultsCache() if cache is not None else None
        tuning_of = cfg if request.tuning_cfg is None else request.tuning_cfg
        data: tuple[Any, Any] | None = None
        out = {}
        with progress_bar(len(methods), "gyro methods", request.progress, unit="methods") as bar:
            for label, method in methods:
                bar.note(label)
                key = None if store is None else results_key(cfg, tuning_of, method, seed, trials)
                j = _stored_j(store, key, label, cache)
                if j is None:
                    if data is None:  # simulated once, only if some method is computed
                        data = (self.simulate(cfg, seed, range(trials)), self.tuning(tuning_of))
                    j = np.asarray(method(cfg, data[0], data[1]), dtype=float)
                    if store is not None and key is not None:
                        store.put(key, Entry({"j": j}, {"label": label}))
                out[label] = np.sqrt(j)
                bar()
        return out


RESULTS_KEY_VERSION = 1
"""Bumped when what a gyro judging entry holds changes."""


def results_key(
    cfg: Any, tuning_cfg: Any, method: Any, seed: int, trials: int
) -> dict[str, Any] | None:
    """The results-cache key of ``method``'s ``J`` per episode on episodes ``seed … seed +
    trials − 1`` of ``cfg``, tuned on :meth:`RedundantGyros.tuning`'s episodes of
    ``tuning_cfg``: the code (every source of ``qkf``, the numerical libraries, the CPU), both
    configs as they bear on results (not their names) and the method
    (:func:`~qkf.core.results_cache.describe`; a policy: its model's SHA-256). None when the
    method cannot be described: it is not cached."""
    from qkf.core.results_cache import code_fingerprint, describe

    token = describe(method)
    if token is None:
        return None

    def bearing(c: Any) -> dict[str, Any]:
        data = c.model_dump(mode="json")
        for name in ("name", "description"):
            data.pop(name, None)
        return dict(data)

    return {
        "kind": "redundant_gyros.trial_j",
        "version": RESULTS_KEY_VERSION,
        "code": code_fingerprint([_QKF]),
        "config": bearing(cfg),
        "tuning": {
            "config": bearing(tuning_cfg),
            "seed": PROBLEM.seeds.tuning[0],
            "episodes": TUNING_EPISODES,
        },
        "method": token,
        "seed": seed,
        "trials": trials,
    }


def _stored_j(
    store: Any, key: dict[str, Any] | None, label: str, cache: CacheLog | None
) -> np.ndarray | None:
    """The stored ``J`` per episode under ``key``, counted in ``cache`` (``off`` without a key);
    a damaged entry is reported (``CacheWarning``, ``cache.problems``) and gives None."""
    from qkf.core.results_cache import CacheWarning

    if store is None or cache is None:
        return None
    if key is None:
        cache.add(label, "off")
        return None
    lookup = store.get(key)
    cache.add(label, lookup.status)
    if lookup.status == "corrupt":
        cache.problems.append(lookup.detail)
        warnings.warn(
            f"damaged results-cache entry of {label}, recomputed: {lookup.detail}",
            CacheWarning,
            stacklevel=3,
        )
    return None if lookup.entry is None else np.asarray(lookup.entry.arrays["j"])


_QKF = Path(__file__).resolve().parents[1]
"""The ``qkf`` package folder: its sources name the code of every gyro method."""


def _resolved(specs: Sequence[str]) -> list[tuple[str, Any]]:
    """``(label, method)`` of each spec, resolved once; ``ValueError`` for a label twice."""
    from qkf.redundant_gyros.methods import resolve_gyro_method

    methods = [resolve_gyro_method(s) for s in specs]
    labels = [label for label, _ in methods]
    twice = sorted({x for x in labels if labels.count(x) > 1})
    if twice:
        raise ValueError(f"{', '.join(twice)}: the same label twice (use LABEL=SPEC)")
    return methods


PROBLEM = RedundantGyros()
"""Registered as ``redundant_gyros`` in :data:`qkf.core.problem.PROBLEMS`."""

__all__ = [
    "CONTROL_FAMILIES",
    "ENV_IDS",
    "FAMILIES",
    "MIXTURE",
    "PROBLEM",
    "SHIFT_FAMILIES",
    "TUNING_EPISODES",
    "RedundantGyros",
]
