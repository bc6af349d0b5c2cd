r"""Baselines tuned on the training mixture: the ``…-mixed`` variants (docs/methods.md, "Tuned
baselines").

A tunable baseline (``kf-tuned``, ``clock``, ``alarm-burst``, the ``-tuned`` variants) tunes on
the *judged* config's tuning seeds: it is told the family, which a policy trained once on the
mixture is not. Its ``-mixed`` variant tunes on the same tuning seeds of the *training mixture*
instead, and then runs on the judged trials with what it found::

    θ*_mixed = tune(cfg with scenario := TRAINING_MIXTURE's, at cfg's dt_s and duration_s)

The whole scenario is the mixture's (its laws of events, ADS noise and truth prior: a shift
family's own law never reaches the tuning); the filter, the action set and the tuning budget
are the judged config's. So the variant differs from its per-family twin only in what it was
tuned on (like for like with a policy trained on the mixture), and one tuning serves every
family judged with the same filter.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from qkf.transfer_alignment.config import Config, Scenario
from qkf.transfer_alignment.methods.base import Method, MethodOutput, prepare
from qkf.transfer_alignment.scenario import ScenarioData

TRAINING_MIXTURE = "mixed_random"
"""The preset whose families every policy of the zoo trains on (docs/zoo.md)."""

MIXED_SUFFIX = "-mixed"


@lru_cache(maxsize=1)
def _mixture_scenario() -> Scenario:
    from qkf.transfer_alignment.config import load_config

    scenario = load_config(TRAINING_MIXTURE).scenario
    if scenario.random_events is None:  # the preset is a mixture: a broken preset is a bug
        raise ValueError(f"the training mixture {TRAINING_MIXTURE} draws no events")
    return scenario


def with_scenario(cfg: Config, scenario: Scenario) -> Config:
    """``cfg`` with ``scenario`` (its laws of events, noise and truth) in place of its own, at
    the judged run's step and duration; the filter and every other section stay ``cfg``'s."""
    update = {"dt_s": cfg.scenario.dt_s, "duration_s": cfg.scenario.duration_s}
    return cfg.model_copy(update={"scenario": scenario.model_copy(update=update)})


def mixture_config(cfg: Config) -> Config:
    """``cfg`` with the training mixture's scenario in place of its own (:func:`with_scenario`)."""
    return with_scenario(cfg, _mixture_scenario())


@dataclass(frozen=True)
class TunedElsewhere:
    """A method prepared on another family's scenario (``tuned_on`` says which): runs it and
    says so in its notes."""

    method: Method
    tuned_on: str = f"the training mixture {TRAINING_MIXTURE}"

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        out = self.method(cfg, data)
        for key, note in out.notes.items():
            out.notes[key] = f"{note} [tuned on {self.tuned_on}]"
        return out


class _BaseSettings:
    """The wrapped method's settings declaration (methods.base.uses_settings) is the
    wrapper's too, so the benchmark resolves and records the section it reads."""

    base: Method

    @property
    def settings_section(self) -> Any:
        return getattr(self.base, "settings_section", None)

    @property
    def settings(self) -> Any:
        return getattr(self.base, "settings", None)

    @property
    def settings_reads(self) -> Any:
        return getattr(self.base, "settings_reads", ())


@dataclass(frozen=True)
class TunedOnMixture(_BaseSettings):
    """The ``-mixed`` variant of a tunable method ``base`` (named ``name``): :meth:`prepare`
    tunes ``base`` on :func:`mixture_config`; the prepared method runs on the judged data."""

    name: str
    base: Method

    def prepare(self, cfg: Config) -> Method:
        return TunedElsewhere(prepare(self.base, mixture_config(cfg)))

    def cache_token(self) -> Any:
        from qkf.core.results_cache import describe

        return {"tuned_on": TRAINING_MIXTURE, "name": self.name, "base": describe(self.base)}

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return self.prepare(cfg)(cfg, data)


@dataclass(frozen=True)
class TunedOnScenario(_BaseSettings):
    """``base`` tuned on another family's scenario (``tuned_on``, its name): :meth:`prepare`
    tunes it on :func:`with_scenario` (the judged config with that scenario: the
    :func:`mixture_config` rule with any family's scenario), and runs what it found on the
    judged data. What ``qkf judge`` makes of a tuned method on a shift family
    (:meth:`~qkf.transfer_alignment.problem.TransferAlignment.trial_errors`)."""

    base: Method
    scenario: Scenario
    tuned_on: str

    def prepare(self, cfg: Config) -> Method:
        return TunedElsewhere(prepare(self.base, with_scenario(cfg, self.scenario)), self.tuned_on)

    def cache_token(self) -> Any:
        from qkf.core.results_cache import describe

        return {
            "tuned_on": self.tuned_on,
            "scenario": self.scenario.model_dump(mode="json"),
            "base": describe(self.base),
        }

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return self.prepare(cfg)(cfg, data)
