"""The method contract (docs/architecture.md, "Add a method") and helpers the methods share.

A *method* is a callable ``method(cfg, data) -> MethodOutput`` that filters every trial of a
:class:`~qkf.transfer_alignment.scenario.ScenarioData` at once. Optionally it has
``prepare(cfg) -> method``: work done once per run, in the driver process, before trials are
dispatched to the backend (the tuned KF picks its κ there); the returned method must be
picklable (a module-level function, or a ``functools.partial`` / dataclass of one).

A method with settings declares the section of ``adaptive`` it reads and the
:class:`~qkf.core.config.StrictModel` that validates it (:func:`uses_settings`), and reads it
with :func:`method_settings`: ``adaptive.<section>`` in YAML and ``--set`` then reach it, are
checked before any work and are recorded in the run's manifest (docs/architecture.md, "Recipe:
add a method"). The built-in methods' sections are fields of
:class:`~qkf.transfer_alignment.adaptive.AdaptiveConfig`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, TypeVar, runtime_checkable

import numpy as np

from qkf.core.config import StrictModel
from qkf.core.problem import MethodOutputError
from qkf.transfer_alignment.config import Config, SettingsT, builtin_section, read_section
from qkf.transfer_alignment.filter import FilterRecord, TransferAlignmentKF
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import ScenarioData


@dataclass
class MethodOutput:
    """A method's estimates for B trials over N epochs (SI).

    ``kappa`` is the process-noise factor in use per trial and epoch (methods that adapt each
    calibration term separately give the geometric mean over the nine terms, a bank its
    probability-weighted geometric mean); ``None`` for a method that does not choose κ.
    ``cov`` is the error covariance the method reports at the epochs of
    :func:`~qkf.transfer_alignment.methods.covariance.covariance_epochs` (NaN where it has
    none); the benchmark judges it by NEES. ``None``: the method reports no covariance.
    ``logs`` holds method-specific arrays for whoever calls the method directly; the benchmark
    does not read them.

    ``var``, ``innov`` and ``nis``: what a method that runs one filter saw at every epoch —
    the diagonal of its a-posteriori covariance, its innovations and their normalised squares.
    Recorded runs without truth are judged by them (docs/recorded_data.md): the ±σ columns of
    ``estimates.csv``, NIS against its χ² band and the innovations' whiteness. ``None``: the
    method does not report them (a bank, a batch solution), and those columns are empty.
    """

    est: np.ndarray  # (B, N, 16): q̂ (scalar-last), b̂ (rad/s), p̂ after each epoch's update
    diverged: np.ndarray  # (B,) bool
    kappa: np.ndarray | None = None  # (B, N) κ in use, finite and positive
    logs: dict[str, np.ndarray] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)  # one-line facts for the summary
    cov: np.ndarray | None = None  # (B, M, 15, 15) at the sampled epochs, SI
    var: np.ndarray | None = None  # (B, N, 15) diagonal of P after each epoch's update, SI
    innov: np.ndarray | None = None  # (B, N, 6) attitude, rate innovations, SI; NaN: none
    nis: np.ndarray | None = None  # (B, N, 2) attitude, rate NIS; NaN without that update


class EpochRecords:
    """The per-epoch fields of :class:`MethodOutput` (``var``, ``innov``, ``nis``) of one filter
    run in blocks: :meth:`put` each block's record, :meth:`attach` them to the output."""

    def __init__(self, n_trials: int, n_epochs: int) -> None:
        self.var = np.full((n_trials, n_epochs, 15), np.nan)
        self.innov = np.full((n_trials, n_epochs, 6), np.nan)
        self.nis = np.full((n_trials, n_epochs, 2), np.nan)

    def put(self, k0: int, rec: FilterRecord) -> None:
        """The record of the block that starts at epoch ``k0``."""
        k1 = k0 + rec.est.shape[1]
        self.var[:, k0:k1] = rec.var
        self.innov[:, k0:k1] = rec.innov
        self.nis[:, k0:k1, 0] = rec.nis_att
        self.nis[:, k0:k1, 1] = rec.nis_rate

    def attach(self, out: MethodOutput) -> MethodOutput:
        out.var, out.innov, out.nis = self.var, self.innov, self.nis
        return out


def with_epoch_records(out: MethodOutput, rec: FilterRecord) -> MethodOutput:
    """``out`` with the per-epoch fields (``var``, ``innov``, ``nis``) of one filter's record."""
    out.var = rec.var
    out.innov = rec.innov
    out.nis = np.stack([rec.nis_att, rec.nis_rate], axis=-1)
    return out


def validate_output(
    out: object, name: str, n_trials: int, n_epochs: int, n_cov: int | None = None
) -> MethodOutput:
    """Check a method's output against the contract; :class:`MethodOutputError` if it fails.

    ``n_cov``: the number of sampled covariance epochs (``cov`` is checked when given).

    Called on every chunk as soon as the method returns, so a malformed output stops the run
    before anything is written.
    """
    where = f"method {name!r}"
    if not isinstance(out, MethodOutput):
        raise MethodOutputError(f"{where} returned {type(out).__name__}, not a MethodOutput")
    est = np.asarray(out.est)
    if est.shape != (n_trials, n_epochs, 16):
        raise MethodOutputError(
            f"{where}: est has shape {est.shape}, expected ({n_trials}, {n_epochs}, 16)"
        )
    div = np.asarray(out.diverged)
    if div.shape != (n_trials,) or div.dtype != np.bool_:
        raise MethodOutputError(
            f"{where}: diverged must be a boolean array of shape ({n_trials},), "
            f"got {div.dtype} {div.shape}"
        )
    if out.kappa is not None:
        kap = np.asarray(out.kappa)
        if kap.shape != (n_trials, n_epochs):
            raise MethodOutputError(
                f"{where}: kappa has shape {kap.shape}, expected ({n_trials}, {n_epochs}): "
                "the κ in use per trial and epoch"
            )
        alive = ~div
        if not np.all(np.isfinite(kap[alive]) & (kap[alive] > 0.0)):
            raise MethodOutputError(f"{where}: kappa must be finite and positive")
    if out.cov is not None and n_cov is not None:
        cov = np.asarray(out.cov)
        if cov.shape != (n_trials, n_cov, 15, 15):
            raise MethodOutputError(
                f"{where}: cov has shape {cov.shape}, expected ({n_trials}, {n_cov}, 15, 15): "
                "the covariance at the sampled epochs (methods.covariance.covariance_epochs)"
            )
    for name, width in (("var", 15), ("innov", 6), ("nis", 2)):
        arr = getattr(out, name)
        if arr is not None and np.shape(arr) != (n_trials, n_epochs, width):
            raise MethodOutputError(
                f"{where}: {name} has shape {np.shape(arr)}, expected "
                f"({n_trials}, {n_epochs}, {width})"
            )
    bad_notes = [k for k, v in out.notes.items() if not isinstance(v, str)]
    if bad_notes:
        raise MethodOutputError(f"{where}: notes must be strings ({', '.join(bad_notes)})")
    return out


@runtime_checkable
class Method(Protocol):
    """``method(cfg, data) -> MethodOutput`` (see the module docstring)."""

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput: ...


def prepare(method: Method, cfg: Config) -> Method:
    """``method.prepare(cfg)`` if the method has it, else the method itself."""
    prep = getattr(method, "prepare", None)
    return prep(cfg) if callable(prep) else method


def new_filter(cfg: Config, data: ScenarioData, n_copies: int = 1) -> TransferAlignmentKF:
    """A filter over ``n_copies`` × B trials (copies of a trial are adjacent), initialised."""
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), data.n_trials * n_copies)
    kf.initialize(np.repeat(data.ads_q[:, 0], n_copies, axis=0))
    return kf


SETTINGS_SECTION = "settings_section"
"""Attribute of a method naming the section of ``adaptive`` it reads (:func:`uses_settings`)."""
SETTINGS_MODEL = "settings"
"""Attribute of a method holding the model of that section (a ``StrictModel`` subclass)."""
SETTINGS_READS = "settings_reads"
"""Attribute of a method naming the other methods' built-in sections it reads as well."""

M = TypeVar("M")


def uses_settings(
    section: str, model: type[StrictModel], reads: tuple[str, ...] = ()
) -> Callable[[M], M]:
    """Declare that the decorated method (a function or a class) reads ``cfg.adaptive.<section>``
    as ``model``, and reads the built-in sections ``reads`` of other methods as well.

    ``model`` is a :class:`~qkf.core.config.StrictModel` subclass: its defaults are the
    method's defaults and its fields are validated (unknown keys refused), so ``section`` in a
    YAML file or ``--set adaptive.<section>.<field>=…`` is checked, with the field named, before
    a benchmark does any work. A built-in section (``imm``) may be declared with its own model
    only. ``reads`` (e.g. ``("tuned",)``, the tuning budget a tuned baseline shares) makes a
    read of another method's section visible where the method is defined; the layering test
    (``tests/test_settings_reads.py``) refuses any ``cfg.adaptive.<section>`` read that no
    declaration covers. The declaration is three attributes (``settings_section``,
    ``settings``, ``settings_reads``); the method reads its own settings as
    ``cfg.adaptive.<section>`` (a built-in one) or with :func:`method_settings`, and anyone
    else reads them through the method with :func:`settings_of`.
    """
    check_declaration(section, model)
    for other in reads:
        if builtin_section(other) is None:
            raise ValueError(f"reads={reads!r}: {other!r} is not a built-in section of adaptive")

    def declare(method: M) -> M:
        setattr(method, SETTINGS_SECTION, section)
        setattr(method, SETTINGS_MODEL, model)
        setattr(method, SETTINGS_READS, tuple(reads))
        return method

    return declare


def check_declaration(section: object, model: object) -> None:
    """``ValueError`` unless ``section`` can name a config section (an identifier, no leading
    underscore: it is a YAML key and a step of a dotted ``--set`` key) and ``model`` is a
    ``StrictModel`` subclass (whose unknown keys are errors)."""
    if not isinstance(section, str) or not section.isidentifier() or section.startswith("_"):
        raise ValueError(
            f"settings section {section!r} must be an identifier without a leading underscore"
        )
    if not (isinstance(model, type) and issubclass(model, StrictModel)):
        raise ValueError(
            f"settings of section {section!r} must be a StrictModel subclass "
            f"(qkf.core.config), not {model!r}"
        )


def declared_settings(method: object) -> tuple[str, type[StrictModel]] | None:
    """The ``(section, model)`` a method declares (:func:`uses_settings`), or None if it
    declares none; ``ValueError`` for a declaration that cannot be used."""
    section = getattr(method, SETTINGS_SECTION, None)
    if section is None:
        return None
    model = getattr(method, SETTINGS_MODEL, None)
    check_declaration(section, model)
    assert isinstance(model, type) and issubclass(model, StrictModel)  # for the type checker
    return section, model


def method_settings(cfg: Config, section: str, model: type[SettingsT]) -> SettingsT:
    """A method's settings: ``cfg.adaptive.<section>`` as ``model`` (the section it declares
    with :func:`uses_settings`), the model's defaults where the config has none.

    Call it where the settings are used, inside the method: it reads the config the method is
    given, so it works in any process a backend runs the method in (the config travels with
    the trials). In a benchmark the section was checked before any work; a config never
    resolved (a method called directly) is checked here. Raises
    :class:`~qkf.core.config.ConfigError` naming ``adaptive.<section>.<field>``.
    """
    return read_section(cfg, section, model)


def declared_sections(method: object) -> tuple[str, ...]:
    """Every section of ``adaptive`` a method declares it reads: its own, then ``reads``."""
    declared = declared_settings(method)
    own = () if declared is None else (declared[0],)
    return own + tuple(getattr(method, SETTINGS_READS, ()))


def settings_of(method: object, cfg: Config, model: type[SettingsT]) -> SettingsT:
    """The settings of ``method`` in ``cfg``, read through its declaration
    (:func:`uses_settings`): how code that is not the method (an environment's controls, a
    tuning budget) reads them, so that what it reads is visible in the method's own file.
    ``model`` is the declared model (for the type checker); ``ValueError`` if the method
    declares none or another."""
    declared = declared_settings(method)
    if declared is None or declared[1] is not model:
        raise ValueError(f"{method!r} does not declare settings of type {model.__name__}")
    return read_section(cfg, declared[0], model)


def action_values(cfg: Config) -> np.ndarray:
    """The κ action set of the config."""
    return np.asarray(cfg.adaptive.actions.values())


def kappa_range(cfg: Config) -> tuple[float, float]:
    """The smallest and largest κ of the action set: where the adaptive rules clip their κ."""
    kappas = action_values(cfg)
    return float(kappas.min()), float(kappas.max())


def decision_steps(period_s: float, dt_s: float) -> int:
    """Filter epochs per decision period (at least one)."""
    return max(1, round(period_s / dt_s))


def per_epoch(per_period: np.ndarray, period: int, n_epochs: int) -> np.ndarray:
    """Expand values held over decision periods (B, T) to every epoch (B, N)."""
    return np.repeat(per_period, period, axis=1)[:, :n_epochs]


def method_rng(data: ScenarioData, trial_row: int, stream: int) -> np.random.Generator:
    """A generator for one trial's own draws by a method, independent of batch and chunking."""
    return np.random.default_rng([data.seed, int(data.trial_ids[trial_row]), 0x9E3779B9, stream])
