"""Monte Carlo benchmark of methods on a scenario: config → scenario → method → metrics → report.

Trials are simulated in chunks (``run.chunk_trials``) by the runner of
:mod:`qkf.core.montecarlo`; every method sees the same simulated data (paired comparison), and
trial ``i`` is the same whatever the chunking or the backend. Methods are prepared once in this
process (:func:`~qkf.transfer_alignment.methods.prepare`), and each output is validated as soon
as a chunk returns it, so a malformed method stops the run before anything is written. Results
are held in memory; :mod:`qkf.transfer_alignment.report` writes them.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from qkf.core.config import ConfigError
from qkf.core.montecarlo import ProgressBar, chunk_ids, progress_bar, run_chunks
from qkf.core.results_cache import CacheWarning, ResultsCache, cache_enabled
from qkf.core.stats import (
    ErrorAccumulator,
    average_nees_band,
    bootstrap_rms,
    min_verdict_trials,
    nees,
    per_trial_comparison,
    percentile_interval,
    resample_counts,
)
from qkf.core.versus import paired_verdict
from qkf.transfer_alignment.adaptive import TUNING_SEEDS, QkfConfig
from qkf.transfer_alignment.chunk_cache import (
    cached_prepare,
    chunk_key,
    from_entry,
    lookup_prepared,
    prepare_at,
    store_prepared,
    to_entry,
)
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.crlb import CrlbResult, crlb
from qkf.transfer_alignment.divergence import Divergence, find_divergences
from qkf.transfer_alignment.methods import (
    BUILTIN_METHODS,
    Method,
    MethodOutput,
    MethodSpecError,
    NamedMethod,
    resolve_method,
    resolve_method_settings,
    validate_output,
)
from qkf.transfer_alignment.methods.base import decision_steps, settings_of
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.methods.qlearning import run_qkf
from qkf.transfer_alignment.metrics import (
    METRIC_COLUMNS,
    state_errors,
    trial_mean_squares,
    window_masks,
)
from qkf.transfer_alignment.params import n_epochs
from qkf.transfer_alignment.scenario import ScenarioData, simulate
from qkf.transfer_alignment.settled import SettledWindows, settled_windows
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUPS

BAND_POINTS = 300
"""About this many epochs carry the bootstrap bands of the RMS curves (plots, rms_bands.csv)."""
BAND_RESAMPLES = 1_000
"""Resamples for the bands (a visual aid; the summary's intervals use ``run.bootstrap``)."""
NEES_COLUMNS: tuple[str, ...] = ("nees_mean", "nees_in_band")
"""summary.csv: the method's own covariance judged by NEES (docs/methods.md, "Consistency")."""


@dataclass
class MethodResult:
    name: str
    rms: np.ndarray  # (N, 15) SI, RMS over trials per epoch
    spec: str | None = field(default=None, kw_only=True)  # how it was asked for (manifest)
    trials: int
    diverged: int
    runtime_s: float
    summary: dict[str, float] = field(default_factory=dict)  # display units, with _lo/_hi
    kappa: np.ndarray | None = None  # (trials, T) κ in use at the sampling times
    notes: dict[str, str] = field(default_factory=dict)
    trial_values: np.ndarray | None = None  # (trials, K) per-trial metrics, display units
    band: np.ndarray | None = None  # (T, groups, 3): RMS, lo, hi at band_t, display units
    nees: np.ndarray | None = None  # (M,) trial-averaged NEES at nees_t (None: no covariance)
    nees_trials: np.ndarray | None = None  # (M,) trials in each average
    divergences: list[Divergence] = field(default_factory=list)  # first epoch per trial


@dataclass
class BenchResult:
    config: Config
    seed: int
    trials: int
    t: np.ndarray
    methods: list[MethodResult]
    bound: CrlbResult
    kappa_t: np.ndarray  # (T,) s, the times at which κ traces are sampled
    backend: str = "local"
    workers: int = 1
    paired: list[PairedRatio] = field(default_factory=list)
    band_t: np.ndarray = field(default_factory=lambda: np.empty(0))  # (T,) s
    nees_t: np.ndarray = field(default_factory=lambda: np.empty(0))  # (M,) s
    # state_settled's weights (15,) SI when not the config's own (state_weights): recorded runs
    weights: np.ndarray | None = None
    # results cache, per method: chunks that were a hit, a miss, a damaged entry, or not cached
    cache: dict[str, dict[str, int]] = field(default_factory=dict)
    cache_problems: list[str] = field(default_factory=list)  # the damaged entries (recomputed)


def kappa_sampling(cfg: Config) -> int:
    """Epochs between the κ samples of ``kappa.csv`` and the κ plot (the QKF's period)."""
    return decision_steps(settings_of(run_qkf, cfg, QkfConfig).period_s, cfg.scenario.dt_s)


def parse_methods(spec: str | list[str]) -> list[NamedMethod]:
    """Resolve ``"kf,qkf"`` (or ``"all"``: the built-in methods) into named methods.

    Raises ``ValueError`` (a :class:`MethodSpecError`) for a spec that cannot be resolved.
    """
    if spec == "all":
        spec = list(BUILTIN_METHODS)
    names = [m.strip() for m in (spec.split(",") if isinstance(spec, str) else spec) if m.strip()]
    if not names:
        raise MethodSpecError("no method given")
    return _unique([resolve_method(m) for m in names])


def refuse_tuning_seed(methods: list[NamedMethod], seed: int) -> None:
    """Refuse to judge methods that tune on the tuning seeds (they have a ``prepare``: kf-tuned,
    the oracle, the clock, the ``-tuned`` baselines …) on a seed of that range: they would be
    judged on the trials they were tuned on (docs/environment.md, "Seed ranges")."""
    low, high = TUNING_SEEDS
    tuned = [m.name for m in methods if callable(getattr(m.method, "prepare", None))]
    if tuned and low <= seed < high:
        raise ConfigError(
            f"seed {seed} is a tuning seed ([{low:,}, {high:,})): {', '.join(tuned)} tune on "
            "those seeds, so no tuning seeds are left to judge them apart from; choose a "
            "judging seed outside that range"
        )


def _unique(named: list[NamedMethod]) -> list[NamedMethod]:
    """The methods with repeats of one spec under one label dropped (a method named twice
    runs once); ``MethodSpecError`` for one label given to two different specs."""
    kept: list[NamedMethod] = []
    seen: set[tuple[str, str | None]] = set()
    for m in named:
        if m.spec is not None and (m.name, m.spec) in seen:
            continue
        seen.add((m.name, m.spec))
        kept.append(m)
    named = kept
    labels = [m.name for m in named]
    twice = sorted({n for n in labels if labels.count(n) > 1})
    if twice:
        raise MethodSpecError(
            f"method {', '.join(twice)} given twice, for different methods (give each its own "
            "LABEL=SPEC; the same method named twice runs once)"
        )
    return named


@dataclass
class ChunkResult:
    """What one chunk of trials contributes, per method (summed in chunk order afterwards)."""

    sum_sq: dict[str, np.ndarray]  # (N, 15) sums over the chunk's trials of squared errors
    trial_ms: dict[str, np.ndarray]  # (B, K) per-trial mean squares of the metrics, display
    count: int
    diverged: dict[str, int]
    runtime_s: dict[str, float]
    kappa: dict[str, np.ndarray | None]
    notes: dict[str, dict[str, str]]
    band_ms: dict[str, np.ndarray] = field(default_factory=dict)  # (B, T, groups) display²
    nees_sum: dict[str, np.ndarray | None] = field(default_factory=dict)  # (M,) sums over trials
    nees_count: dict[str, np.ndarray] = field(default_factory=dict)  # (M,) trials summed
    divergences: dict[str, list[Divergence]] = field(default_factory=dict)
    cache: dict[str, str] = field(default_factory=dict)  # per method: hit, miss, corrupt, off
    cache_problems: list[str] = field(default_factory=list)  # corrupt entries found (recomputed)


def band_epochs(n: int) -> np.ndarray:
    """The epochs that carry the bootstrap bands: about :data:`BAND_POINTS`, the last included."""
    step = max(1, n // BAND_POINTS)
    return np.unique(np.append(np.arange(0, n, step), n - 1))


DataSource = Callable[[Config, int, np.ndarray], ScenarioData]
"""``source(cfg, seed, trial ids) -> ScenarioData``: where a benchmark's trials come from
(:func:`~qkf.transfer_alignment.scenario.simulate` unless recorded data are given)."""

KeepOutput = Callable[[str, np.ndarray, MethodOutput], None]
"""``keep(method, trial ids, output)``: called by :func:`run_chunk` with every method's output
on a chunk (in-process runs only): recorded runs write the estimates from it."""

MethodReport = Callable[[str, np.ndarray, bool], None]
"""``report(method, trial ids, finished)``: called by :func:`run_chunk` as each method starts
and finishes on a chunk (progress; in-process runs only, it does not travel to workers)."""


def run_chunk(
    cfg: Config,
    methods: list[NamedMethod],
    seed: int,
    ids: np.ndarray,
    *,
    report: MethodReport | None = None,
    source: DataSource = simulate,
    keep: KeepOutput | None = None,
    weights: np.ndarray | None = None,
    cache: bool = False,
) -> ChunkResult:
    """Simulate trials ``ids`` (or take them from ``source``) and run every method on them (the
    unit of work of a backend).

    ``report``: see :data:`MethodReport` (progress only; the results do not depend on it);
    ``keep``: see :data:`KeepOutput`; ``weights``: those of ``state_settled`` (SI) for data that are
    not a simulation of ``cfg`` (judged from ``run.settled_s``), else each trial's own
    (:func:`~qkf.transfer_alignment.settled.settled_windows`). ``cache``: take each
    method's part from the results cache where it holds it, and store what is computed
    (simulated trials only, without ``keep`` or ``weights``; :mod:`.chunk_cache`);
    ``ChunkResult.cache`` says per method ``hit``, ``miss``, ``corrupt`` or ``off``.
    """
    res = ChunkResult({}, {}, ids.size, {}, {}, {}, {})
    store = (
        ResultsCache()
        if cache and source is simulate and keep is None and weights is None
        else None
    )
    keys: dict[str, dict[str, object] | None] = {}
    for m in methods:
        keys[m.name] = None if store is None else chunk_key(cfg, m.method, seed, ids)
        found = None
        key = keys[m.name]
        if store is not None and key is not None:
            lookup = store.get(key)
            found = lookup.entry
            res.cache[m.name] = lookup.status
            if lookup.status == "corrupt":
                res.cache_problems.append(lookup.detail)
        else:
            res.cache[m.name] = "off"
        if found is not None:
            _set_parts(res, m.name, from_entry(found, m.name))
    todo = [m for m in methods if res.cache[m.name] != "hit"]
    if not todo:
        if report is not None:
            for m in methods:
                report(m.name, ids, False)
                report(m.name, ids, True)
        return res
    data = source(cfg, seed, ids)
    windows = settled_windows(cfg, data, weights)
    for m in methods:
        if report is not None:
            report(m.name, ids, False)
        if res.cache[m.name] != "hit":
            parts = _method_parts(cfg, m, data, ids, keep, windows)
            _set_parts(res, m.name, parts)
            key = keys[m.name]
            if store is not None and key is not None:
                store.put(key, to_entry(parts))
        if report is not None:
            report(m.name, ids, True)
    return res


def _method_parts(
    cfg: Config,
    m: NamedMethod,
    data: ScenarioData,
    ids: np.ndarray,
    keep: KeepOutput | None,
    windows: SettledWindows,
) -> dict[str, object]:
    """Run one method on a chunk's trials: its fields of :class:`ChunkResult`."""
    n = n_epochs(cfg.scenario)
    cov_epochs = covariance_epochs(cfg)
    w = windows.weights / DISPLAY_UNIT  # state_settled's, in display units
    t0 = time.perf_counter()
    out = validate_output(m.method(cfg, data), m.name, data.n_trials, n, cov_epochs.size)
    runtime = time.perf_counter() - t0
    if keep is not None:
        keep(m.name, ids, out)
    err = state_errors(out.est, data.q_true, data.bias, data.calib)
    sq = (err[:, band_epochs(n)] / DISPLAY_UNIT) ** 2
    nees_sum, nees_count = None, np.zeros(cov_epochs.size, np.int64)
    if out.cov is not None:
        val = nees(err[:, cov_epochs], np.asarray(out.cov))  # (B, M); NaN: none or diverged
        ok = np.isfinite(val) & ~np.asarray(out.diverged)[:, None]
        nees_sum, nees_count = np.where(ok, val, 0.0).sum(axis=0), ok.sum(axis=0)
    return {
        "sum_sq": np.sum(err * err, axis=0),
        "trial_ms": trial_mean_squares(err / DISPLAY_UNIT, data.t, windows.first, w),
        "band_ms": np.stack([np.mean(sq[..., sl], axis=-1) for sl in GROUPS.values()], axis=-1),
        "kappa": None
        if out.kappa is None
        else np.asarray(out.kappa)[:, np.arange(0, n, kappa_sampling(cfg))],
        "nees_sum": nees_sum,
        "nees_count": nees_count,
        "diverged": int(np.count_nonzero(out.diverged)),
        "runtime_s": runtime,
        "notes": dict(out.notes),
        "divergences": find_divergences(m.name, out, data.t, ids),
    }


def _set_parts(res: ChunkResult, name: str, parts: dict[str, Any]) -> None:
    res.sum_sq[name] = parts["sum_sq"]
    res.trial_ms[name] = parts["trial_ms"]
    res.band_ms[name] = parts["band_ms"]
    res.kappa[name] = parts["kappa"]
    res.nees_sum[name] = parts["nees_sum"]
    res.nees_count[name] = parts["nees_count"]
    res.diverged[name] = parts["diverged"]
    res.runtime_s[name] = parts["runtime_s"]
    res.notes[name] = parts["notes"]
    res.divergences[name] = parts["divergences"]


def _bar_label(labels: list[str], backend: str, workers: int) -> str:
    """The progress bar's short description: ``bench: 10 methods`` (``, pool`` or ``, ray``
    when the trials run in other processes), never the list of labels (it collapsed the bar
    at 80 columns)."""
    what = labels[0] if len(labels) == 1 else f"{len(labels)} methods"
    if backend == "local" and workers <= 1:
        return f"bench: {what}"
    return f"bench: {what}, {'pool' if backend == 'local' else backend}"


def _short(label: str, width: int = 16) -> str:
    return label if len(label) <= width else label[: width - 1] + "…"


def _method_progress(bar: ProgressBar) -> MethodReport:
    """Advance ``bar`` by one method-trial per trial as each method finishes on a chunk, and
    show the method in progress with its trials (1-based, as a user counts them)."""

    def report(name: str, ids: np.ndarray, finished: bool) -> None:
        if finished:
            bar(int(ids.size))
        else:
            bar.note(f"{_short(name)} · trials {int(ids[0]) + 1}–{int(ids[-1]) + 1}")

    return report


def run_benchmark(
    cfg: Config,
    methods: str | Sequence[str | NamedMethod],
    trials: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    backend: str = "local",
    workers: int | None = None,
    source: DataSource = simulate,
    keep: KeepOutput | None = None,
    bound: CrlbResult | None = None,
    weights: np.ndarray | None = None,
    cache: bool = False,
) -> BenchResult:
    """Run every method on the same ``trials`` Monte Carlo trials of ``cfg``'s scenario.

    ``methods``: specs (``"kf,qkf"``, ``["kf", "mypkg.mod:run"]``) or resolved methods
    (:class:`NamedMethod`), in any mix.
    ``backend``: ``local`` (in this process when ``workers`` is 1, else a process pool) or
    ``ray``; chunks are combined in chunk order, so every backend gives the same numbers.
    The methods' settings sections are checked first (:func:`resolve_method_settings`:
    ``ConfigError`` before any work), and the result's ``config`` is the resolved one.
    ``source`` / ``keep``: recorded data instead of simulated trials, and a hook that sees
    every method's output (:data:`DataSource`, :data:`KeepOutput`; in this process only);
    ``bound`` / ``weights``: the CRLB of the report and the ``state_settled`` weights (SI),
    when not those of ``cfg``'s simulated scenario (recorded data). ``cache``: reuse and store
    each method's results per chunk (:mod:`.chunk_cache`; off where ``$QKF_NO_CACHE`` is
    set); ``BenchResult.cache`` counts the hits and misses, and a damaged entry found on the
    way is reported by a :class:`CacheWarning` and recomputed.
    """
    cache = cache_enabled(cache)
    trials = cfg.run.trials if trials is None else trials
    seed = cfg.run.seed if seed is None else seed
    workers = cfg.run.workers if workers is None else workers
    if trials < 1:
        raise ValueError("trials must be at least 1")
    named = (
        parse_methods(methods)
        if isinstance(methods, str)
        else [m if isinstance(m, NamedMethod) else resolve_method(m) for m in methods]
    )
    named = _unique(named)  # a method named twice runs once
    labels = [m.name for m in named]
    refuse_tuning_seed(named, seed)
    # the methods' settings sections, checked before any work; the resolved config (user
    # sections with their defaults written in) is what every chunk and the manifest see
    cfg = resolve_method_settings(cfg, named)
    specs = {m.name: m.spec for m in named}
    n = n_epochs(cfg.scenario)
    acc = {m: ErrorAccumulator(n) for m in labels}
    runtime = dict.fromkeys(labels, 0.0)
    kappas: dict[str, list[np.ndarray]] = {m: [] for m in labels}
    trial_ms: dict[str, list[np.ndarray]] = {m: [] for m in labels}
    notes: dict[str, dict[str, str]] = {m: {} for m in labels}
    band_ms: dict[str, list[np.ndarray]] = {m: [] for m in labels}
    nees_sum: dict[str, np.ndarray | None] = dict.fromkeys(labels)
    nees_count = {m: np.zeros(covariance_epochs(cfg).size, np.int64) for m in labels}
    divergences: dict[str, list[Divergence]] = {m: [] for m in labels}
    chunks = chunk_ids(trials, cfg.run.chunk_trials)
    # in this process the bar moves per method and chunk (a run of <= 64 trials is one chunk);
    # trials that run in other processes report back per chunk only
    in_process = backend == "local" and workers <= 1
    if keep is not None and not in_process:
        raise ValueError("keep= needs the trials run in this process (local, one worker)")
    label = _bar_label(labels, backend, workers)
    with progress_bar(trials * len(labels), label, progress, "method-trials") as bar:
        # the tuning stage: a note per method that tunes, with the time left estimated from
        # those done so far; inside the bar, a method's tuning in prepare() shows as its own
        # counted row (Optuna's evaluations)
        tuning = [m.name for m in named if callable(getattr(m.method, "prepare", None))]
        prepare_cache: dict[str, str] = {}
        ready: dict[str, Method] = {}
        if not in_process and len(tuning) > 1:
            # the tunings side by side on the backend, those not in the results cache
            found = {x.name: lookup_prepared(x.method, cfg, cache) for x in named
                     if x.name in tuning}  # fmt: skip
            todo = [x for x in named if x.name in tuning and found[x.name][0] is None]
            bar.note(f"tuning {len(todo)} methods side by side ({backend})")
            tune = partial(prepare_at, cfg, tuple(x.method for x in todo))
            ones = [np.array([i]) for i in range(len(todo))]
            tuned = run_chunks(tune, ones, backend, workers, cfg.run.ray_address)
            for x, result in zip(todo, tuned, strict=True):
                store_prepared(found[x.name][2], result[0])
                ready[x.name] = result[0]
            for name, (method, status, _) in found.items():
                if method is not None:  # from the cache
                    ready[name] = method
                prepare_cache[name] = status
        prepared = []
        started = time.perf_counter()
        for one in named:
            if one.name in ready:
                prepared.append(NamedMethod(one.name, ready[one.name]))
                continue
            if one.name in tuning:
                done = tuning.index(one.name)
                left = (time.perf_counter() - started) / done * (len(tuning) - done) if done else 0
                eta = f", about {left:.0f} s left" if done and left >= 1 else ""
                bar.note(f"tuning {done + 1}/{len(tuning)}: {one.name}{eta}")
            method, prepare_cache[one.name] = cached_prepare(one.method, cfg, cache)
            prepared.append(NamedMethod(one.name, method))
        bar.note(None if in_process else f"0/{trials} trials")
        task = (
            partial(
                run_chunk,
                cfg,
                prepared,
                seed,
                report=_method_progress(bar),
                source=source,
                keep=keep,
                weights=weights,
                cache=cache,
            )
            if in_process
            else partial(
                run_chunk, cfg, prepared, seed, source=source, weights=weights, cache=cache
            )
        )
        cache_counts = {m: dict.fromkeys(("hit", "miss", "corrupt", "off"), 0) for m in labels}
        damaged: list[str] = []
        for m, status in prepare_cache.items():  # the preparation counts as one lookup
            if status != "off":
                cache_counts[m][f"prepare_{status}"] = 1
            if status == "corrupt":
                damaged.append(f"damaged results-cache entry of {m}'s preparation, recomputed")
                warnings.warn(damaged[-1], CacheWarning, stacklevel=2)
        done = 0
        for res in run_chunks(task, chunks, backend, workers, cfg.run.ray_address):
            for problem in res.cache_problems:
                damaged.append(f"damaged results-cache entry, recomputed: {problem}")
                warnings.warn(damaged[-1], CacheWarning, stacklevel=2)
            for m in labels:
                cache_counts[m][res.cache[m]] += 1
                acc[m].add_sums(res.sum_sq[m], res.count, res.diverged[m])
                runtime[m] += res.runtime_s[m]
                trial_ms[m].append(res.trial_ms[m])
                trace = res.kappa[m]
                if trace is not None:
                    kappas[m].append(trace)
                notes[m].update(res.notes[m])
                band_ms[m].append(res.band_ms[m])
                divergences[m] += res.divergences[m]
                part = res.nees_sum[m]
                if part is not None:
                    prev = nees_sum[m]
                    nees_sum[m] = part if prev is None else prev + part
                    nees_count[m] += res.nees_count[m]
            done += res.count
            if not in_process:
                bar(res.count * len(labels))
            bar.note(f"{done}/{trials} trials")
    # per-trial metric values as written to trials.csv; the summary and its intervals are
    # computed from exactly these numbers (summary = sqrt(mean over trials of value²))
    values = {m: np.sqrt(np.concatenate(trial_ms[m])) for m in labels}
    boot = cfg.run.bootstrap
    counts = resample_counts(trials, boot.resamples, seed)
    replicates = {m: bootstrap_rms(values[m] ** 2, counts) for m in labels}
    band_counts = resample_counts(trials, min(BAND_RESAMPLES, boot.resamples), seed + 1)
    t = np.arange(n) * cfg.scenario.dt_s
    nees_t = t[covariance_epochs(cfg)]
    results = []
    for m in labels:
        nees_avg = nees_sum[m]
        if nees_avg is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                nees_avg = nees_avg / nees_count[m]
        summary_nees = nees_summary(nees_avg, nees_count[m], nees_t, cfg.run.settled_s, boot.level)
        rms = acc[m].rms()
        point = column_rms(values[m])
        lo, hi = percentile_interval(replicates[m], boot.level)
        summary: dict[str, float] = {}
        for j, col in enumerate(METRIC_COLUMNS):
            summary[col], summary[f"{col}_lo"], summary[f"{col}_hi"] = (
                float(point[j]),
                float(lo[j]),
                float(hi[j]),
            )
        summary.update(summary_nees)
        results.append(
            MethodResult(
                name=m,
                rms=rms,
                trials=acc[m].count,
                diverged=acc[m].diverged,
                runtime_s=runtime[m],
                summary=summary,
                trial_values=values[m],
                kappa=np.concatenate(kappas[m]) if kappas[m] else None,
                notes=notes[m],
                spec=specs[m],
                band=rms_bands(np.concatenate(band_ms[m]), band_counts, boot.level),
                nees=nees_avg,
                nees_trials=nees_count[m],
                divergences=divergences[m],
            )
        )
    return BenchResult(
        config=cfg,
        seed=seed,
        trials=trials,
        t=t,
        methods=results,
        bound=crlb(cfg) if bound is None else bound,
        kappa_t=np.arange(0, n, kappa_sampling(cfg)) * cfg.scenario.dt_s,
        backend=backend,
        workers=workers,
        paired=paired_ratios(
            labels, values, replicates, baselines(cfg, labels), boot.level, counts
        ),
        band_t=t[band_epochs(n)],
        nees_t=nees_t,
        weights=weights,
        cache=cache_counts,
        cache_problems=damaged,
    )


def rms_bands(ms: np.ndarray, counts: np.ndarray, level: float) -> np.ndarray:
    """RMS over trials and its percentile-bootstrap band: ``ms`` (trials, T, G) per-trial mean
    squares → (T, G, 3) = RMS, lo, hi. Trials that are not finite throughout (diverged) are left
    out of the band (its RMS then describes the finite trials only)."""
    finite = np.isfinite(ms).all(axis=(1, 2))
    use = np.where(finite[:, None, None], ms, 0.0)
    n_ok = max(1, int(finite.sum()))
    point = np.sqrt(use.sum(axis=0) / n_ok)
    w = counts * finite[None, :]
    reps = np.sqrt(np.tensordot(w, use, axes=1) / np.maximum(w.sum(axis=1), 1.0)[:, None, None])
    lo, hi = percentile_interval(reps, level)
    return np.stack([point, lo, hi], axis=-1)


def nees_summary(
    avg: np.ndarray | None, count: np.ndarray, t: np.ndarray, settled_s: float, level: float
) -> dict[str, float]:
    """``nees_mean``: the trial-averaged NEES divided by its dimension (15), averaged over the
    sampled epochs of the settled window (1 for a consistent filter); ``nees_in_band``: the
    fraction of those epochs whose trial-averaged NEES lies inside the two-sided χ² band of
    ``level`` (``χ²(15·n)/n`` for an average over n trials). NaN without a covariance."""
    nan = {c: float("nan") for c in NEES_COLUMNS}
    if avg is None or t.size == 0:
        return nan
    use = window_masks(t, settled_s)["settled"] & (count > 0) & np.isfinite(avg)
    if not use.any():
        return nan
    lo, hi = average_nees_band(15, count[use], level)
    inside = (avg[use] >= lo) & (avg[use] <= hi)
    return {"nees_mean": float(np.mean(avg[use]) / 15.0), "nees_in_band": float(np.mean(inside))}


def column_rms(values: np.ndarray) -> np.ndarray:
    """``sqrt(mean(v²))`` of each column of (trials, K), column by column as 1-D arrays, so that
    recomputing a summary value from one column of trials.csv gives the same bits."""
    return np.array([np.sqrt(np.mean(np.ascontiguousarray(col) ** 2)) for col in values.T])


@dataclass(frozen=True)
class PairedRatio:
    """``method`` against ``baseline`` on one metric: the pooled RMS ratio with its paired
    bootstrap interval, and per trial the median ratio with its interval, P(improve) and the
    worst decile (:class:`~qkf.core.stats.PerTrialComparison`); ``judged``: enough trials for a
    verdict (:func:`~qkf.core.stats.min_verdict_trials`)."""

    method: str
    baseline: str
    metric: str
    ratio: float
    lo: float
    hi: float
    median: float = float("nan")
    median_lo: float = float("nan")
    median_hi: float = float("nan")
    p_improve: float = float("nan")
    worst_decile: float = float("nan")
    judged: bool = True

    @property
    def verdict(self) -> str:
        """``better`` when the pooled ratio's interval and the median per-trial ratio's are
        both below 1, ``worse`` when both are above, ``unjudged`` with too few trials, else
        ``inconclusive`` (docs/methods.md, "Per-trial verdicts")."""
        return paired_verdict(self.lo, self.hi, self.median_lo, self.median_hi, self.judged)


def baselines(cfg: Config, labels: list[str]) -> list[str]:
    """The baselines of the paired comparisons: ``kf`` and ``run.baseline``, those that ran."""
    return [b for b in dict.fromkeys(["kf", cfg.run.baseline]) if b in labels]


def paired_ratios(
    labels: list[str],
    values: dict[str, np.ndarray],
    replicates: dict[str, np.ndarray],
    bases: list[str],
    level: float,
    counts: np.ndarray,
) -> list[PairedRatio]:
    """Every method against every baseline, every metric: the RMS ratio on all trials and its
    percentile interval over the *same* resamples ``counts`` of trials for both (a paired
    bootstrap), and the per-trial comparison over the same resamples."""
    out = []
    judged = counts.shape[1] >= min_verdict_trials(level)
    for base in bases:
        point_b = column_rms(values[base])
        for m in labels:
            if m == base:
                continue
            point = column_rms(values[m])
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = point / point_b
                lo, hi = percentile_interval(replicates[m] / replicates[base], level)
            per = per_trial_comparison(values[m], values[base], counts, level)
            for j, col in enumerate(METRIC_COLUMNS):
                pooled_part = (float(ratio[j]), float(lo[j]), float(hi[j]))
                trial_part = (
                    float(per.median[j]), float(per.median_lo[j]), float(per.median_hi[j]),
                    float(per.p_improve[j]), float(per.worst_decile[j]),
                )  # fmt: skip
                out.append(PairedRatio(m, base, col, *pooled_part, *trial_part, judged))
    return out
