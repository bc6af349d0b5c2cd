r"""The κ methods of the gyro calibration episodes, by name: what a gyro policy is judged against
(docs/redundant_gyros.md, "Methods").

A method schedules κ (the factor on the UKF's process noise) over one episode of the gyro
environments and is scored by the hindsight's criterion ``J`` (:mod:`.hindsight`): the settled
mean square of the four calibrated states over their prior sd. Its judged error per episode is
``e = √J`` (dimensionless), so that RMS ratios over episodes are ``√(ΣJ_A / ΣJ_B)``.

Every method is called as ``method(cfg, episodes, tuning)``: ``episodes`` the judged episodes
(:func:`~.hindsight.episode`), ``tuning`` the episodes of the tuning seeds, which the tuned
methods pick their settings on (the same for every method: the same budget of data), never the
judged ones. It returns ``J`` per judged episode (``inf`` where the filter fails).

=================== ======================================================================
``constant``        the best constant κ of the action set on the tuning episodes
``clock``           the tuned clock: κ_a, then κ_c from a switch time (:mod:`.clock`)
``nis-adaptive``    innovation-based adaptive κ, its gain, half-life and start tuned
                    (:mod:`.nis_adaptive`)
``sage-husa``       Sage–Husa's process-noise estimate projected onto κ, its forgetting
                    factor and start tuned (:mod:`.sage_husa`)
``vb-noise``        variational-Bayes estimates of the process- and measurement-noise scales,
                    their ratio as κ; the scales adapted, their memory and start tuned
                    (:mod:`.vb_noise`)
``constant-mixed``  ``constant``, ``clock``, ``nis-adaptive``, ``sage-husa``, ``vb-noise``
                    tuned instead on the episodes of
``clock-mixed``     the training mixture (``gyro_mixture``'s onsets in the judged config:
``nis-adaptive-``   :func:`with_mixture`): like for like with a policy trained on the mixture
``mixed``, …        (the ``-mixed`` twins of transfer alignment)
``level-informed``  each episode's own best constant κ: knows the episode's noise levels
                    (a bound, not a causal method)
``hindsight``       each episode's best schedule found with the truth (:func:`~.hindsight.search`;
                    a bound)
=================== ======================================================================

A method spec is ``NAME``, ``LABEL=NAME`` or ``FACTORY:ARG`` (``LABEL=FACTORY:ARG``): a
factory of :data:`GYRO_METHOD_FACTORIES` makes the method from ``ARG``; ``agents`` declares
``policy:PATH``, a saved gyro policy run in its environment (:mod:`agents.policy`,
entry-point group ``qkf.gyro_method_factories``), so this package never imports it.

Adding one: a function of that signature, ``GYRO_METHODS.register(name, fn)``, or from another
distribution the entry-point group ``qkf.gyro_methods``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from qkf.core.config import ConfigError
from qkf.core.registry import Registry, RegistryError
from qkf.redundant_gyros import clock, nis_adaptive, sage_husa, vb_noise
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros.config import GyrosConfig

R = TypeVar("R")

GyroMethod = Callable[[GyrosConfig, Sequence[hs.Episode], Sequence[hs.Episode]], np.ndarray]
"""``(cfg, judged episodes, tuning episodes) → J`` per judged episode."""

GYRO_METHODS: Registry[GyroMethod] = Registry("gyro method", group="qkf.gyro_methods")
"""The gyro methods by name (module docstring)."""

GYRO_METHOD_FACTORIES: Registry[Callable[[str], GyroMethod]] = Registry(
    "gyro method factory", group="qkf.gyro_method_factories"
)
"""``FACTORY:ARG`` specs: the factory called with ``ARG`` makes the method (module docstring)."""

BOUNDS = ("level-informed", "hindsight")
"""Methods that know the episode's truth: references for the headroom, never a baseline to
beat."""


@GYRO_METHODS.register("constant")
def run_constant(
    cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
) -> np.ndarray:
    """The constant κ of the action set with the lowest mean ``J`` over ``tuning``."""
    best = hs.best_constant(np.stack([hs.constant_scores(ep) for ep in tuning]))
    return np.array([hs.constant_scores(ep)[best] for ep in episodes])


@GYRO_METHODS.register("clock")
def run_clock(
    cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
) -> np.ndarray:
    """The clock of :mod:`.clock`'s grid with the lowest mean ``J`` over ``tuning``."""
    tuned, _ = clock.tune_on(cfg, tuning)
    return np.array([clock.score(ep, tuned) for ep in episodes])


@GYRO_METHODS.register("nis-adaptive")
def run_nis_adaptive(
    cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
) -> np.ndarray:
    """The innovation-based rule of :mod:`.nis_adaptive`'s grid best over ``tuning``."""
    rule, _ = nis_adaptive.tune_on(nis_adaptive.EpisodeBatch.of_episodes(cfg, tuning))
    return nis_adaptive.run_rule_on(nis_adaptive.EpisodeBatch.of_episodes(cfg, episodes), rule)


@GYRO_METHODS.register("sage-husa")
def run_sage_husa(
    cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
) -> np.ndarray:
    """The Sage–Husa κ of :mod:`.sage_husa`'s grid best over ``tuning``."""
    return _tuned_covariance_rule(cfg, episodes, tuning, sage_husa.tune_on, sage_husa.run_rule_on)


@GYRO_METHODS.register("vb-noise")
def run_vb_noise(
    cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
) -> np.ndarray:
    """The variational-Bayes noise scales of :mod:`.vb_noise`'s grid best over ``tuning``."""
    return _tuned_covariance_rule(cfg, episodes, tuning, vb_noise.tune_on, vb_noise.run_rule_on)


def _tuned_covariance_rule(
    cfg: GyrosConfig,
    episodes: Sequence[hs.Episode],
    tuning: Sequence[hs.Episode],
    tune_on: Callable[[nis_adaptive.EpisodeBatch], tuple[R, float]],
    run_rule_on: Callable[[nis_adaptive.EpisodeBatch, R], np.ndarray],
) -> np.ndarray:
    """``J`` per judged episode of a rule that reads each epoch's covariance (the UKFs keep
    it), tuned by ``tune_on`` on the ``tuning`` episodes and run by ``run_rule_on``."""
    batch = nis_adaptive.EpisodeBatch.of_episodes
    rule, _ = tune_on(batch(cfg, tuning, keep_cov=True))
    return run_rule_on(batch(cfg, episodes, keep_cov=True), rule)


@GYRO_METHODS.register("level-informed")
def run_level_informed(
    cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
) -> np.ndarray:
    """Each episode's own best constant κ (a bound: it knows the episode's levels)."""
    return np.array([float(np.min(hs.constant_scores(ep))) for ep in episodes])


@GYRO_METHODS.register("hindsight")
def run_hindsight(
    cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
) -> np.ndarray:
    """Each episode's best schedule found with its truth (a bound)."""
    return np.array([hs.search(ep).score for ep in episodes])


MIXTURE_PRESET = "gyro_mixture"
"""The preset whose ``onset_mixture`` the ``-mixed`` methods tune on."""


def with_mixture(cfg: GyrosConfig) -> GyrosConfig:
    """``cfg`` with the onsets of the training mixture (:data:`MIXTURE_PRESET`) in place of its
    own, everything else (unit, filter, duration, actions) kept: what the ``-mixed`` methods
    tune on. ``ConfigError`` when the mixture's gyro is not in ``cfg``'s unit."""
    from qkf.redundant_gyros import load_config

    mixture = load_config(MIXTURE_PRESET).scenario.onset_mixture
    known = {g.id for g in cfg.unit.gyros}
    gyros = {c.onset.gyro for c in mixture or [] if c.onset is not None}
    if not gyros <= known:
        raise ConfigError(
            f"the training mixture's onsets are on gyro {', '.join(sorted(gyros))}, not in this "
            f"unit ({', '.join(sorted(known))}): the -mixed methods cannot tune on it"
        )
    scenario = cfg.scenario.model_copy(update={"onset": None, "onset_mixture": mixture})
    return cfg.model_copy(update={"scenario": scenario})


def _tuned_on_mixture(method: GyroMethod) -> GyroMethod:
    """``method`` tuned on the tuning episodes of :func:`with_mixture` (the same seeds as every
    tuned method's: ``RedundantGyros.tuning``), whatever family it is judged on."""

    def run(
        cfg: GyrosConfig, episodes: Sequence[hs.Episode], tuning: Sequence[hs.Episode]
    ) -> np.ndarray:
        from qkf.redundant_gyros.problem import PROBLEM

        return method(cfg, episodes, PROBLEM.tuning(with_mixture(cfg)))

    run.__doc__ = f"{method.__name__}, tuned on the training mixture's episodes."
    return run


for _name, _method in (
    ("constant", run_constant),
    ("clock", run_clock),
    ("nis-adaptive", run_nis_adaptive),
    ("sage-husa", run_sage_husa),
    ("vb-noise", run_vb_noise),
):
    GYRO_METHODS.register(f"{_name}-mixed", _tuned_on_mixture(_method))


def resolve_gyro_method(spec: str) -> tuple[str, GyroMethod]:
    """``(label, method)`` of a method spec (module docstring); ``ValueError`` naming the spec
    and the known names for one that cannot be resolved. A factory's method may offer a
    ``default_label`` (a policy: its folder's name)."""
    label, sep, target = (part.strip() for part in spec.strip().partition("="))
    if not sep:
        label, target = "", spec.strip()
    if sep and not label:
        raise ValueError(f"{spec!r}: empty label before '='")
    name, colon, arg = target.partition(":")
    try:
        method = GYRO_METHOD_FACTORIES[name](arg) if colon else GYRO_METHODS[target]
    except ConfigError:  # a factory's own refusal names what it refused
        raise
    except (RegistryError, OSError, ValueError) as exc:  # a factory refusing its argument too
        raise ValueError(f"{spec!r}: {exc}") from None
    default = getattr(method, "default_label", None)
    return label or (default if isinstance(default, str) else target), method


__all__ = [
    "BOUNDS",
    "GYRO_METHODS",
    "GYRO_METHOD_FACTORIES",
    "GyroMethod",
    "resolve_gyro_method",
    "run_clock",
    "run_constant",
    "run_hindsight",
    "run_level_informed",
    "run_nis_adaptive",
    "run_sage_husa",
    "run_vb_noise",
    "with_mixture",
]
