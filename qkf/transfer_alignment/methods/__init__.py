"""Ways of choosing the process-noise factor κ of the transfer-alignment filter (docs/methods.md).

Every method filters all trials of a :class:`~qkf.transfer_alignment.scenario.ScenarioData` at
once and returns a :class:`MethodOutput` (contract: :mod:`.base`). ``qkf bench --methods`` takes
*method specs*, resolved by :func:`resolve_method`:

``NAME``
    a registered method: the built-ins of :data:`METHODS`, or one an installed package adds
    through the entry-point group ``qkf.methods`` (``name = "pkg.module:function"``);
``FACTORY:ARGUMENT``
    a registered method factory called with the argument, e.g. ``policy:PATH`` (a saved agent;
    :data:`METHOD_FACTORIES`, entry-point group ``qkf.method_factories``);
``package.module:function``
    any importable function — no registration needed;
``LABEL=SPEC``
    any of the above, shown as ``LABEL`` in tables and plots (a method may suggest its own
    short name through a ``default_label`` attribute: ``policy:PATH`` uses the model's file
    stem, or its folder's name for the usual ``model.zip``/``model.npz``).

A method's settings live in its own section of ``adaptive`` (:func:`.base.uses_settings`,
:func:`.base.method_settings`); :func:`resolve_method_settings` checks a config's sections
against the methods of a run.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from qkf.core.config import ConfigError, StrictModel
from qkf.core.registry import Registry, RegistryError, load_object
from qkf.transfer_alignment.config import Config, resolve_sections
from qkf.transfer_alignment.methods.alarm_burst import run_alarm_burst
from qkf.transfer_alignment.methods.base import (
    Method,
    MethodOutput,
    MethodOutputError,
    declared_settings,
    method_settings,
    prepare,
    uses_settings,
    validate_output,
)
from qkf.transfer_alignment.methods.batch import run_batch
from qkf.transfer_alignment.methods.clock import run_clock
from qkf.transfer_alignment.methods.covariance_matching import run_covariance_matching
from qkf.transfer_alignment.methods.fading import run_fading
from qkf.transfer_alignment.methods.fixed import run_kf, run_kf_tuned
from qkf.transfer_alignment.methods.glr import run_glr
from qkf.transfer_alignment.methods.hindsight import run_hindsight
from qkf.transfer_alignment.methods.hindsight_moves import hindsight_moves_method
from qkf.transfer_alignment.methods.imm import run_imm
from qkf.transfer_alignment.methods.mmae import run_mmae
from qkf.transfer_alignment.methods.nis_rule import run_nis_rule
from qkf.transfer_alignment.methods.on_mixture import MIXED_SUFFIX, TunedOnMixture
from qkf.transfer_alignment.methods.oracle import run_oracle
from qkf.transfer_alignment.methods.qlearning import run_qkf
from qkf.transfer_alignment.methods.sage_husa import run_sage_husa
from qkf.transfer_alignment.methods.tuned import TUNED_METHODS
from qkf.transfer_alignment.methods.vbakf import run_vbakf

METHODS: Registry[Method] = Registry("method", group="qkf.methods")
"""Methods by name: the package's own first, in their default order, then installed ones."""
_BUILTIN: tuple[tuple[str, Method], ...] = (
    ("kf", run_kf),
    ("kf-tuned", run_kf_tuned),
    ("sage-husa", run_sage_husa),
    ("qkf", run_qkf),
    ("mmae", run_mmae),
    ("imm", run_imm),
    ("fading", run_fading),
    ("vbakf", run_vbakf),
    ("covariance-matching", run_covariance_matching),
    ("batch", run_batch),
)
for _name, _method in _BUILTIN:
    METHODS.register(_name, _method)

BUILTIN_METHODS: tuple[str, ...] = tuple(name for name, _ in _BUILTIN)
"""The package's own methods (``--methods all`` runs these)."""

METHODS.register("oracle", run_oracle)
"""A reference, not a method: it reads the truth (docs/methods.md, "Oracle schedule"); so it is
registered but not part of ``--methods all``."""

METHODS.register("alarm-burst", run_alarm_burst)
"""A flight method (it reads only the innovations), but tuned like the oracle (its κ_base,
κ_after and W are the oracle's, 66 tuning runs), so it is named explicitly rather than run by
``--methods all``."""

METHODS.register("glr", run_glr)
"""A flight method (a CUSUM on the innovations that re-opens the calibration block of P);
named explicitly, beside its tuned variant ``glr-tuned``."""

METHODS.register("nis-rule", run_nis_rule)
"""A flight method: κ_burst for hold_s after any NIS alarm, else κ_base (docs/methods.md, "NIS
rule"); the simplest rule that mimics the learned policies. Named explicitly, beside
``nis-rule-tuned``."""

METHODS.register("clock", run_clock)
"""A yardstick, not a flight method: the best open-loop κ(t), tuned with the truth."""

METHODS.register("hindsight", run_hindsight)
"""A yardstick: per trial, the best κ schedule with that trial's truth known (the bound)."""

for _name, _tuned in TUNED_METHODS.items():
    METHODS.register(_name, _tuned)
"""The ``-tuned`` variants: hyperparameters tuned by Optuna on the tuning seeds (cached)."""

TUNABLE: tuple[str, ...] = ("kf-tuned", "clock", "alarm-burst", *TUNED_METHODS)
"""The methods that tune on the tuning seeds of the config they are given: each also has a
``…-mixed`` variant tuned on the training mixture (:mod:`.on_mixture`)."""
for _name in TUNABLE:
    METHODS.register(_name + MIXED_SUFFIX, TunedOnMixture(_name + MIXED_SUFFIX, METHODS[_name]))

YARDSTICKS: tuple[str, ...] = ("oracle", "clock", "clock-mixed", "hindsight")
"""References that read the truth (per trial or on the tuning seeds): never flight methods."""

METHOD_FACTORIES: Registry[Callable[[str], Method]] = Registry(
    "method factory", group="qkf.method_factories"
)
"""``FACTORY:ARGUMENT`` specs: ``factory(argument) -> method``."""
METHOD_FACTORIES.register("hindsight-moves", hindsight_moves_method)
"""A yardstick: per trial, the best schedule of the moves of a v4 action space
(``hindsight-moves:kappa+reset+r_scale``) with the trial's truth known."""


class MethodSpecError(ValueError):
    """A method spec that cannot be resolved; the message says why."""


@dataclass(frozen=True)
class NamedMethod:
    """A resolved method, the name it is reported under and the spec it came from (None for a
    method passed as an object: such a run cannot be repeated from its manifest)."""

    name: str
    method: Method
    spec: str | None = None


def resolve_method(spec: str) -> NamedMethod:
    """The method a spec names (see the module docstring); :class:`MethodSpecError` if none."""
    spec = spec.strip()
    label, sep, target = spec.partition("=")
    if not sep:
        label, target = "", spec
    label, target = label.strip(), target.strip()
    if sep and not label:
        raise MethodSpecError(f"{spec!r}: empty label before '='")
    if not target:
        raise MethodSpecError(f"{spec!r}: no method")
    try:
        method = _resolve_target(target)
    except RegistryError as exc:
        raise MethodSpecError(str(exc)) from None
    if not callable(method):
        raise MethodSpecError(f"{target!r} is not callable")
    try:  # a settings declaration that cannot be used is the method's fault: refuse it here
        declared_settings(method)
    except ValueError as exc:
        raise MethodSpecError(f"{target!r}: {exc}") from None
    # a factory may suggest a shorter name than its spec (policy:PATH → the model's folder)
    default = getattr(method, "default_label", None)
    return NamedMethod(label or (default if isinstance(default, str) else target), method, spec)


def _resolve_target(target: str) -> Method:
    if target in METHODS:
        return METHODS[target]
    head, sep, arg = target.partition(":")
    if not sep:
        raise MethodSpecError(
            f"unknown method {target!r}; known: {', '.join(METHODS.names())}, "
            f"{', '.join(f'{f}:ARG' for f in METHOD_FACTORIES.names())}, or module:function"
        )
    if head in METHOD_FACTORIES:
        try:
            return METHOD_FACTORIES[head](arg)
        except (OSError, ValueError) as exc:
            raise MethodSpecError(f"{target!r}: {exc}") from None
    return load_object(target)


def resolve_method_settings(
    cfg: Config, methods: Iterable[NamedMethod], source: str = "config"
) -> Config:
    """``cfg`` with the settings sections of ``methods`` checked and resolved, before any work.

    Each method's declared section (:func:`.base.uses_settings`) is validated by its model, its
    defaults written in where the config leaves them out (so the manifest records what ran);
    a user section of ``adaptive`` that none of ``methods`` reads is refused as an unknown key.
    Two methods may share a section only with the same model. ``source`` names the config in
    the messages (the file or preset); raises :class:`~qkf.core.config.ConfigError` with every
    problem, one line each, ``source: adaptive.<section>.<field>: message``.

    :func:`~qkf.transfer_alignment.benchmark.run_benchmark` calls it; a command that loads a
    config and resolves ``--methods`` calls it too, with the config's name, to refuse a bad
    setting with the file named before it prepares its output. A method object that offers
    ``check(cfg)`` (``policy:PATH``: its action set) is asked too.
    """
    methods = list(methods)
    claims: dict[str, tuple[type[StrictModel], str]] = {}
    for m in methods:
        try:
            declared = declared_settings(m.method)
        except ValueError as exc:
            raise MethodSpecError(f"method {m.name!r}: {exc}") from None
        if declared is None:
            continue
        section, model = declared
        earlier = claims.setdefault(section, (model, f"method {m.name!r}"))
        if earlier[0] is not model:
            raise ConfigError(
                f"{source}: adaptive.{section}: read by {earlier[1]} as {earlier[0].__name__} "
                f"and by method {m.name!r} as {model.__name__}; a section has one model"
            )
    resolved = resolve_sections(cfg, claims, source)
    for m in methods:  # a method object's own refusal (a policy of another action set)
        check = getattr(m.method, "check", None)
        if callable(check):
            check(resolved)
    return resolved


__all__ = [
    "BUILTIN_METHODS",
    "METHODS",
    "METHOD_FACTORIES",
    "YARDSTICKS",
    "Method",
    "MethodOutput",
    "MethodOutputError",
    "MethodSpecError",
    "NamedMethod",
    "method_settings",
    "prepare",
    "resolve_method",
    "resolve_method_settings",
    "uses_settings",
    "validate_output",
]
