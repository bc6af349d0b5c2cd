r"""Tuned baselines: the classical methods with their hyperparameters searched by Optuna
(docs/methods.md, "Tuned baselines").

For a method with settings θ, its ``-tuned`` variant runs with::

    θ* = argmin over the evaluated θ of J(θ),   J(θ) = sqrt( mean_i s_i(θ)² )

(``J = ∞`` if a trial diverged), where ``s_i(θ)`` is the settled-window score
``adaptive.tuned.metric`` (dimensionless for ``state_settled``, SI for a group;
:mod:`qkf.transfer_alignment.judging`) of tuning trial i, filtered by the method with θ. The
tuning trials are ``adaptive.tuned.trials`` trials of seed ``adaptive.tuned.seed`` (a range
disjoint from every judged seed), as for ``kf-tuned``. The θ evaluated are
``adaptive.optuna.evaluations`` in all: first the method's own settings θ₀ (its section of
``adaptive`` as configured; for ``alarm-burst`` also the oracle's schedule it borrows), then
settings proposed by Optuna's TPE sampler (multivariate, seeded with
``adaptive.optuna.sampler_seed``), which sees θ₀'s score as its first observation. θ* replaces
θ₀ only if it scores strictly lower, so ``J(θ*) ≤ J(θ₀)`` on the tuning trials by
construction. A study is deterministic: the same config gives the same θ*.

Search spaces (:data:`TUNED_METHODS`; a range is widened to hold θ₀ if it lies outside):

- log-uniform where a setting acts by its order of magnitude (a prior weight, a threshold, a
  window length, a σ);
- a forgetting factor ρ is searched as ``1 − ρ`` log-uniform (its memory ``1/(1 − ρ)`` in
  measurements is what matters);
- a κ is one of the action set (``adaptive.actions``), searched by its index (ordered);
- switches (``adapt_r`` …) and modes (``switching``) are categorical.

The study runs once per benchmark, in ``prepare`` (driver process), and its result is cached as
JSON under ``$QKF_CACHE_DIR/tuning/`` (default ``~/.cache/qkf/tuning/``), one file per key: the
method, the scenario and filter sections, ``run.settled_s`` and ``run.settle_factor`` (they set
the judged window), the
action set, ``adaptive.tuned``, ``adaptive.optuna``, the method's own settings sections, the
search space and :data:`CACHE_VERSION`. A file is written atomically (temporary file, then
``os.replace``); a cached result is used only if its recorded key equals the wanted one and its
fields are well-formed, else the study runs again and rewrites it.

Cost: one evaluation is one run of the method over ``trials × epochs`` (:func:`tuning_budget`);
measured times per method are in docs/methods.md.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np

from qkf.core.config import StrictModel
from qkf.core.montecarlo import progress_stage
from qkf.transfer_alignment.adaptive import OptunaConfig
from qkf.transfer_alignment.config import Config, epochs_of
from qkf.transfer_alignment.judging import estimate_scores, pooled
from qkf.transfer_alignment.methods.alarm_burst import AlarmBurstSchedule, run_alarm_burst
from qkf.transfer_alignment.methods.base import Method, MethodOutput, action_values, uses_settings
from qkf.transfer_alignment.methods.covariance_matching import run_covariance_matching
from qkf.transfer_alignment.methods.fading import run_fading
from qkf.transfer_alignment.methods.glr import run_glr
from qkf.transfer_alignment.methods.imm import run_imm
from qkf.transfer_alignment.methods.nis_rule import run_nis_rule
from qkf.transfer_alignment.methods.oracle import OracleSchedule, tune_oracle
from qkf.transfer_alignment.methods.sage_husa import run_sage_husa
from qkf.transfer_alignment.methods.vbakf import run_vbakf
from qkf.transfer_alignment.scenario import ScenarioData, simulate

if TYPE_CHECKING:
    import optuna

CACHE_VERSION = 2
"""Part of every cache key: raise it when a method's behaviour changes, so that no study of
the old code is reused. 2: the judged window and weights became per trial
(:mod:`qkf.transfer_alignment.settled`)."""

Setting = float | int | bool | str
ParamKind = Literal["float", "log", "int", "log_int", "memory", "choice", "action"]


@dataclass(frozen=True)
class Param:
    """One hyperparameter of a search space.

    ``kind``: ``float`` uniform on ``[low, high]``; ``log`` log-uniform; ``int`` / ``log_int``
    integers, uniform / log-uniform; ``memory`` a forgetting factor ρ ∈ ``[low, high]``
    searched as ``1 − ρ`` log-uniform; ``choice`` one of ``choices``; ``action`` a κ of the
    action set, searched by its index. ``low``/``high`` in the setting's own units.
    """

    name: str
    kind: ParamKind
    low: float = 0.0
    high: float = 0.0
    choices: tuple[Setting, ...] = ()

    def covering(self, value: Setting) -> Param:
        """This parameter with its range widened (or its choices extended) to hold ``value``."""
        if self.kind == "choice":
            return (
                self
                if value in self.choices
                else dataclasses.replace(self, choices=(*self.choices, value))
            )
        v = float(value)
        log = self.kind in ("log", "log_int")
        if self.kind == "action" or (log and v <= 0.0):
            return self  # not representable: told to the sampler as its nearest (trial_value)
        return dataclasses.replace(self, low=min(self.low, v), high=max(self.high, v))

    def suggest(self, trial: optuna.Trial, actions: np.ndarray) -> Setting:
        """A value for ``trial`` (the setting itself, in its units)."""
        n = self.name
        if self.kind == "float":
            return trial.suggest_float(n, self.low, self.high)
        if self.kind == "log":
            return trial.suggest_float(n, self.low, self.high, log=True)
        if self.kind in ("int", "log_int"):
            log = self.kind == "log_int"
            return trial.suggest_int(n, int(self.low), int(self.high), log=log)
        if self.kind == "memory":  # ρ = 1 − x, x log-uniform
            return 1.0 - trial.suggest_float(
                f"one_minus_{n}", 1 - self.high, 1 - self.low, log=True
            )
        if self.kind == "choice":
            return cast(Setting, trial.suggest_categorical(n, self.choices))
        return float(actions[trial.suggest_int(f"{n}_index", 0, actions.size - 1)])

    def show(self, value: Setting) -> str:
        """``value`` for a note: 4 significant digits (a forgetting factor: those of 1 − ρ)."""
        if not isinstance(value, float):
            return str(value)
        return f"1 − {1.0 - value:.4g}" if self.kind == "memory" else f"{value:.4g}"

    def distribution(
        self, actions: np.ndarray
    ) -> tuple[str, optuna.distributions.BaseDistribution]:
        """The Optuna parameter name and distribution :meth:`suggest` uses."""
        from optuna.distributions import (
            CategoricalDistribution,
            FloatDistribution,
            IntDistribution,
        )

        n = self.name
        if self.kind in ("float", "log"):
            return n, FloatDistribution(self.low, self.high, log=self.kind == "log")
        if self.kind in ("int", "log_int"):
            return n, IntDistribution(int(self.low), int(self.high), log=self.kind == "log_int")
        if self.kind == "memory":
            return f"one_minus_{n}", FloatDistribution(1 - self.high, 1 - self.low, log=True)
        if self.kind == "choice":
            return n, CategoricalDistribution(self.choices)
        return f"{n}_index", IntDistribution(0, actions.size - 1)

    def trial_value(self, value: Setting, actions: np.ndarray) -> Setting:
        """The Optuna parameter value of a setting (for telling the study about θ₀); a κ not
        in the action set is given the nearest action's index (in log κ)."""
        if self.kind == "choice":
            return value
        if self.kind == "action":
            return int(np.argmin(np.abs(np.log(actions) - math.log(float(value)))))
        # clipped to the range: a value :meth:`covering` cannot hold (ρ = 1, W = 0 on a log
        # scale) is told as the nearest end
        if self.kind == "memory":
            return min(max(1.0 - float(value), 1.0 - self.high), 1.0 - self.low)
        v = min(max(float(value), self.low), self.high)
        return round(v) if self.kind in ("int", "log_int") else v


@dataclass(frozen=True)
class TuningResult:
    """What a study found (and what the cache holds): θ*, J(θ*), θ₀, J(θ₀), and every
    evaluated setting with its score, in the order evaluated."""

    settings: dict[str, Setting]
    score: float
    defaults: dict[str, Setting]
    default_score: float
    history: list[tuple[dict[str, Setting], float]]


@dataclass(frozen=True)
class TunedSetting:
    """A tuned method with its settings fixed (what :meth:`OptunaTuned.prepare` returns):
    picklable, it runs the base method with the config updated with ``settings``."""

    tuner: OptunaTuned
    settings: tuple[tuple[str, Setting], ...]
    note: str = ""

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        run_cfg, method = self.tuner.build(cfg, dict(self.settings))
        out = method(run_cfg, data)
        if self.note:
            out.notes[self.tuner.name] = self.note
        return out


@dataclass(frozen=True)
@uses_settings("optuna", OptunaConfig, reads=("tuned",))
class OptunaTuned:
    """The ``-tuned`` variant of a method whose settings are the section ``section`` of
    ``adaptive``: ``space`` is searched (module docstring), the rest of the section stays as
    configured. Tuned once per benchmark in :meth:`prepare`; called unprepared, it tunes on
    the spot."""

    name: str
    base: Method
    section: str
    space: tuple[Param, ...]

    def sections(self) -> tuple[str, ...]:
        """The sections of ``adaptive`` whose values change what the study finds."""
        return (self.section,)

    def defaults(self, cfg: Config) -> dict[str, Setting]:
        """θ₀: the configured values of the searched settings."""
        section = getattr(cfg.adaptive, self.section)
        return {p.name: getattr(section, p.name) for p in self.space}

    def build(self, cfg: Config, settings: Mapping[str, Setting]) -> tuple[Config, Method]:
        """The config to run the base method with (its section updated with ``settings``,
        validated by the section's model) and the method to run."""
        return with_section(cfg, self.section, settings), self.base

    def prepare(self, cfg: Config) -> TunedSetting:
        key = cache_key(self, cfg)
        path = cache_path(self.name, key)
        result = read_cache(path, key, self)
        if result is None:
            result = run_study(self, cfg)
            write_cache(path, key, result)
        return TunedSetting(self, tuple(result.settings.items()), self.note(cfg, result))

    def note(self, cfg: Config, result: TuningResult) -> str:
        """The summary line: budget, θ*, J(θ*) and J(θ₀)."""
        tc, oc = cfg.adaptive.tuned, cfg.adaptive.optuna
        params = ", ".join(f"{p.name} = {p.show(result.settings[p.name])}" for p in self.space)
        return (
            f"tuned with Optuna: {oc.evaluations} evaluations × {tc.trials} trials of seed "
            f"{tc.seed} on {tc.metric}: {params}; score {result.score:.4g} "
            f"(defaults {result.default_score:.4g})"
        )

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return self.prepare(cfg)(cfg, data)


SCHEDULE = ("kappa_base", "kappa_after", "window_s")
"""The alarm-burst settings that are not in its section: the oracle's schedule it borrows."""


@dataclass(frozen=True)
@uses_settings("optuna", OptunaConfig, reads=("tuned", "alarm_burst", "oracle"))
class AlarmBurstTuned(OptunaTuned):
    """``alarm-burst-tuned``: the alarm settings (``adaptive.alarm_burst``) and the schedule
    ``(κ_base, κ_after, W)`` tuned jointly. θ₀ is what ``alarm-burst`` runs with: its section
    as configured and the oracle's schedule, tuned with the truth on the same trials."""

    def sections(self) -> tuple[str, ...]:
        return (self.section, "oracle")

    def defaults(self, cfg: Config) -> dict[str, Setting]:
        section = cfg.adaptive.alarm_burst
        orc = tune_oracle(cfg, progress_label=f"tune {self.name} (θ₀)")
        schedule = {"kappa_base": orc.base, "kappa_after": orc.after, "window_s": orc.window_s}
        return {
            p.name: schedule[p.name] if p.name in SCHEDULE else getattr(section, p.name)
            for p in self.space
        }

    def build(self, cfg: Config, settings: Mapping[str, Setting]) -> tuple[Config, Method]:
        own = {k: v for k, v in settings.items() if k not in SCHEDULE}
        orc = OracleSchedule(
            base=float(settings["kappa_base"]),
            after=float(settings["kappa_after"]),
            window_s=float(settings["window_s"]),
        )
        return with_section(cfg, self.section, own), AlarmBurstSchedule(orc)


def with_section(cfg: Config, section: str, settings: Mapping[str, Setting]) -> Config:
    """``cfg`` with ``adaptive.<section>`` updated with ``settings`` (validated: a value the
    section's model refuses raises)."""
    current: StrictModel = getattr(cfg.adaptive, section)
    updated = type(current).model_validate({**current.model_dump(), **settings})
    adaptive = cfg.adaptive.model_copy(update={section: updated})
    return cfg.model_copy(update={"adaptive": adaptive})


def study_space(tuner: OptunaTuned, defaults: Mapping[str, Setting]) -> tuple[Param, ...]:
    """The tuner's space, each range widened to hold its default."""
    return tuple(p.covering(defaults[p.name]) for p in tuner.space)


@contextmanager
def quiet_optuna() -> Iterator[None]:
    """Optuna's per-trial log lines off (warnings still shown), restored afterwards."""
    import optuna

    before = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        yield
    finally:
        optuna.logging.set_verbosity(before)


def run_study(tuner: OptunaTuned, cfg: Config) -> TuningResult:
    """The Optuna study of ``tuner`` on the tuning trials of ``cfg`` (module docstring)."""
    import optuna

    tc, oc = cfg.adaptive.tuned, cfg.adaptive.optuna
    # its own row under the benchmark's progress bar: one tick per evaluated setting
    advance = progress_stage(f"tune {tuner.name}", oc.evaluations, "tuning runs")
    data = simulate(cfg, tc.seed, tc.trials)
    actions = action_values(cfg)
    history: list[tuple[dict[str, Setting], float]] = []

    def evaluate(settings: dict[str, Setting]) -> float:
        run_cfg, method = tuner.build(cfg, settings)
        out = method(run_cfg, data)
        score = pooled(estimate_scores(cfg, out.est, data, tc.metric), out.diverged)
        history.append((settings, score))
        advance(1)
        return score

    defaults = tuner.defaults(cfg)
    space = study_space(tuner, defaults)
    with quiet_optuna():
        sampler = optuna.samplers.TPESampler(seed=oc.sampler_seed, multivariate=True)
        study = optuna.create_study(direction="minimize", sampler=sampler)
        # θ₀ is evaluated exactly as configured (not through the search's parametrization,
        # which could change its last bit), then told to the sampler as its first observation
        default_score = evaluate(dict(defaults))
        dists = dict(p.distribution(actions) for p in space)
        params = {
            p.distribution(actions)[0]: p.trial_value(defaults[p.name], actions) for p in space
        }
        study.add_trial(
            optuna.trial.create_trial(params=params, distributions=dists, value=default_score)
        )

        def objective(trial: optuna.Trial) -> float:
            return evaluate({p.name: p.suggest(trial, actions) for p in space})

        if oc.evaluations > 1:
            study.optimize(objective, n_trials=oc.evaluations - 1)
    best, best_score = history[0]
    for settings, score in history[1:]:
        if score < best_score:  # strictly better, so θ₀ wins a tie
            best, best_score = settings, score
    return TuningResult(best, best_score, dict(defaults), default_score, history)


# ---- the cache ---------------------------------------------------------------------------------


def cache_dir() -> Path:
    """``$QKF_CACHE_DIR/tuning`` (default ``~/.cache/qkf/tuning``)."""
    root = os.environ.get("QKF_CACHE_DIR") or os.path.join("~", ".cache", "qkf")
    return Path(root).expanduser() / "tuning"


def cache_key(tuner: OptunaTuned, cfg: Config) -> dict[str, Any]:
    """Everything a study's result depends on (module docstring), as JSON-ready values."""
    adaptive = cfg.adaptive
    return {
        "version": CACHE_VERSION,
        "method": tuner.name,
        "scenario": cfg.scenario.model_dump(mode="json"),
        "filter": cfg.filter.model_dump(mode="json"),
        "settled_s": cfg.run.settled_s,
        "settle_factor": cfg.run.settle_factor,
        "actions": adaptive.actions.model_dump(mode="json"),
        "tuned": adaptive.tuned.model_dump(mode="json"),
        "optuna": adaptive.optuna.model_dump(mode="json"),
        "settings": {s: getattr(adaptive, s).model_dump(mode="json") for s in tuner.sections()},
        "space": [dataclasses.asdict(p) for p in tuner.space],
    }


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def cache_path(name: str, key: Mapping[str, Any]) -> Path:
    """The file of a key: ``<name>-<first 16 hex digits of the key's SHA-256>.json``."""
    digest = hashlib.sha256(_canonical(key).encode()).hexdigest()[:16]
    return cache_dir() / f"{name}-{digest}.json"


def write_cache(path: Path, key: Mapping[str, Any], result: TuningResult) -> None:
    """Write ``result`` under ``key`` atomically (a reader never sees half a file)."""
    doc = {
        "key": key,
        "settings": result.settings,
        "score": result.score,
        "defaults": result.defaults,
        "default_score": result.default_score,
        "history": [{"settings": s, "score": v} for s, v in result.history],
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}-", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1)  # inf scores are written as Infinity (Python reads it)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_cache(path: Path, key: Mapping[str, Any], tuner: OptunaTuned) -> TuningResult | None:
    """The cached result of ``key``, or None if there is none or the file is unreadable,
    written for another key, or malformed (then the study runs again and rewrites it)."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    try:
        if _canonical(doc["key"]) != _canonical(key):
            return None
        names = {p.name for p in tuner.space}

        def settings(value: Any) -> dict[str, Setting]:
            if not isinstance(value, dict) or set(value) != names:
                raise ValueError("settings do not match the search space")
            if not all(isinstance(v, float | int | bool | str) for v in value.values()):
                raise ValueError("a setting is not a number, switch or name")
            return dict(value)

        def number(value: Any) -> float:
            if isinstance(value, bool) or not isinstance(value, float | int):
                raise ValueError("a score is not a number")
            return float(value)

        history = [(settings(h["settings"]), number(h["score"])) for h in doc["history"]]
        return TuningResult(
            settings(doc["settings"]),
            number(doc["score"]),
            settings(doc["defaults"]),
            number(doc["default_score"]),
            history,
        )
    except (KeyError, TypeError, ValueError):
        return None


# ---- the budget --------------------------------------------------------------------------------


@dataclass(frozen=True)
class TuningBudget:
    """The filter work of one tuned method's study: ``evaluations × trials × epochs``."""

    evaluations: int
    trials: int
    epochs: int

    @property
    def trial_epochs(self) -> int:
        return self.evaluations * self.trials * self.epochs

    def __str__(self) -> str:
        return (
            f"{self.evaluations} evaluations × {self.trials} trials × {self.epochs} epochs "
            f"= {self.trial_epochs:.3g} trial-epochs per tuned method"
        )


def tuning_budget(cfg: Config) -> TuningBudget:
    """The budget of a study under ``cfg`` (``alarm-burst-tuned`` adds the oracle's tuning
    runs for its θ₀)."""
    return TuningBudget(
        cfg.adaptive.optuna.evaluations, cfg.adaptive.tuned.trials, epochs_of(cfg.scenario)
    )


# ---- the variants ------------------------------------------------------------------------------

KAPPA = Param("kappa", "action")

_VARIANTS: tuple[OptunaTuned, ...] = (
    OptunaTuned(
        "vbakf-tuned",
        run_vbakf,
        "vbakf",
        (
            Param("tau", "log", 0.03, 300.0),  # weight of the nominal prediction
            Param("forgetting", "memory", 0.9, 0.999),  # R memory 10 … 1000 measurements
            Param("r_prior_dof", "log", 0.3, 300.0),
            Param("iterations", "log_int", 1, 10),
            Param("adapt_p", "choice", choices=(True, False)),
            Param("adapt_r", "choice", choices=(True, False)),
        ),
    ),
    OptunaTuned(
        "imm-tuned",
        run_imm,
        "imm",
        (
            Param("p_stay", "memory", 0.7, 0.9999),  # mean stay 3 … 10⁴ mixing intervals
            Param("switching", "choice", choices=("uniform", "neighbours")),
            Param("mix_every", "log_int", 1, 30),
        ),
    ),
    OptunaTuned(
        "sage-husa-tuned",
        run_sage_husa,
        "sage_husa",
        (
            Param("forgetting", "memory", 0.5, 0.9999),  # memory 2 … 10⁴ epochs
            Param("adapt_r", "choice", choices=(False, True)),
        ),
    ),
    OptunaTuned(
        "covariance-matching-tuned",
        run_covariance_matching,
        "covariance_matching",
        (
            Param("window", "log_int", 1, 1000),  # measurement epochs
            Param("warmup_s", "float", 0.0, 600.0),
            Param("adapt_r", "choice", choices=(True, False)),
        ),
    ),
    OptunaTuned(
        "fading-tuned",
        run_fading,
        "fading",
        (
            Param("forgetting", "log", 0.3, 30.0),  # ρ: V remembers about 1 + ρ epochs
            Param("softening", "log", 1.0, 30.0),  # β ≥ 1
            Param("lambda_max", "log", 1.0, 1000.0),
        ),
    ),
    AlarmBurstTuned(
        "alarm-burst-tuned",
        run_alarm_burst,  # what it tunes; build() runs its rule with the tuned schedule
        "alarm_burst",
        (
            Param("nis_alarm", "log", 1.5, 50.0),  # mean NIS per row of a 10 s period
            Param("quiet_s", "float", 0.0, 1800.0),
            Param("kappa_base", "action"),
            Param("kappa_after", "action"),
            Param("window_s", "log", 10.0, 1600.0),
        ),
    ),
    OptunaTuned(
        "glr-tuned",
        run_glr,
        "glr",
        (
            Param("inflation", "log", 1.5, 100.0),  # λ
            Param("threshold", "log", 3.0, 300.0),  # h, nats
            Param("reset_ppm", "log", 10.0, 3000.0),  # σ_r, ppm or µrad
            Param("quiet_s", "float", 0.0, 1800.0),
            KAPPA,
        ),
    ),
    OptunaTuned(
        "nis-rule-tuned",
        run_nis_rule,
        "nis_rule",
        (
            Param("nis_threshold", "log", 1.5, 50.0),  # mean NIS per row of a period
            Param("kappa_base", "action"),
            Param("kappa_burst", "action"),
            Param("hold_s", "log", 10.0, 1600.0),
        ),
    ),
)

TUNED_METHODS: dict[str, OptunaTuned] = {t.name: t for t in _VARIANTS}
"""The tuned variants by name (``vbakf-tuned`` …): method objects with ``prepare``."""

__all__ = [
    "TUNED_METHODS",
    "OptunaTuned",
    "TunedSetting",
    "TuningBudget",
    "tuning_budget",
]
