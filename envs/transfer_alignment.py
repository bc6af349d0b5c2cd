r"""Gymnasium environment ``qkf/TransferAlignment-v0`` (docs/environment.md).

One episode is one realisation of a scenario (truth and noise drawn from ``np_random`` at
reset); one step is one decision period (``period_s``, 10 s by default) in which the
transfer-alignment filter runs with the process-noise factor κ the agent chose. An episode has
``ceil(duration / period)`` steps, from the config (``env.unwrapped.episode_steps``); the
environment truncates itself there, so ``gym.make`` and ``gym.make_vec`` agree for any duration.

Arguments: ``scenario`` (preset name, config path or ``Config``), ``action_type``
(``discrete`` | ``continuous``), ``reward`` (a name of :data:`envs.rewards.REWARDS`),
``overrides`` (``--set`` style), ``period_s``, ``render_mode`` (``None`` or ``"rgb_array"``:
:meth:`~TransferAlignmentEnv.render` returns a frame of the episode so far, below).

=====================  ===================================================================
Action                 Meaning
=====================  ===================================================================
``Discrete(A)``        index into the κ action set (default 11 values, 0.01 … 100)
``Box(-1, 1, (1,))``   ``action_type="continuous"``: linear in ``log10 κ`` over the set's range
=====================  ===================================================================

=====  ==========================================================  ===========================
Obs    Meaning (float32)                                           Typical scale
=====  ==========================================================  ===========================
0      mean ``log10(σ/σ₀)`` of the attitude block of P              −3 … 0
1      same, bias block                                             −3 … 0
2      same, calibration block                                      −3 … 0
3      mean attitude NIS over the period / 3                        ~1 (jumps at events)
4      mean rate NIS over the period / 3 (0 without rate matching)  ~1
5      log-likelihood gain over the κ = 1 filter, per epoch & row   1e-6 … 1e-4
6      elapsed fraction of the episode                              0 … 1
7      ``|ω̂|``, deg/s                                              0.06 … 1
8      κ index scaled to [0, 1]                                     0 … 1
=====  ==========================================================  ===========================

Rewards: see :mod:`envs.rewards`. ``info`` carries the true errors at the end of the period in
display units (``errors``: 15 values, the ``crlb.csv`` column order), the CRLB there
(``crlb``), ``kappa``, ``t_s`` and ``diverged``. A filter that goes non-finite ends the episode
(``terminated=True``).

Rendering: with ``render_mode="rgb_array"`` each step records four numbers (κ, and the RMS over
the nine calibration terms of the filter's σ, of the true error and of the CRLB, ppm and µrad);
``render()`` draws them into a small RGB frame (``FRAME_HEIGHT_PX × FRAME_WIDTH_PX × 3`` uint8)
and nothing is drawn in ``step``. ``render_mode=None`` (the default) records nothing and
``render()`` returns ``None``. Stable-Baselines3's ``make_vec_env`` asks for ``"rgb_array"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from envs.episodes import DEFAULT_PERIOD_S, EpisodeDriver, StepOutput
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.states import DISPLAY_UNIT

RENDER_MODES: tuple[str, ...] = ("rgb_array",)
"""The render modes of the qkf environments besides ``None`` (Gymnasium's ``metadata``)."""
RENDER_FPS = 10
"""Frames per second of a recorded video (Gymnasium's ``metadata["render_fps"]``): one frame
per decision period, so a 3600-s episode of 10-s periods plays in 36 s. A display rate, not a
physical one."""
FRAME_HEIGHT_PX = 240
FRAME_WIDTH_PX = 320
_FRAME_DPI = 80  # figure inches × dpi = pixels; small fonts stay legible at 320 × 240
CALIBRATION = slice(6, 15)
"""The nine calibration states (scale factors, misalignments) in the 15-value error state."""


def check_render_mode(render_mode: str | None) -> None:
    """Accept ``None`` and the modes of :data:`RENDER_MODES`; anything else is a ``ValueError``
    raised at construction, before any work is done."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        modes = ", ".join(repr(m) for m in (None, *RENDER_MODES))
        raise ValueError(f"render_mode {render_mode!r} is not supported; use one of {modes}")


def calibration_rms(values: np.ndarray) -> np.ndarray:
    """RMS over the nine calibration terms of display-unit state values (last axis 15): ppm and
    µrad are both 1e-6, so the mixed RMS is meaningful in "ppm/µrad"."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged filter: inf/NaN, drawn as gaps
        return np.sqrt(np.mean(np.square(values[..., CALIBRATION]), axis=-1))


class EpisodeTrace:
    """What ``render()`` draws: per step of the current episode, the time (s), the κ in use and
    a few positive curves on one log axis. Appending is a few list appends (cheap enough for
    every step); drawing happens only in :meth:`frame`.

    ``curves``: the curve labels; ``ylabel``: their axis label; ``kappa_range``: the smallest and
    largest κ of the action set (fixes the κ axis); ``time_range_s``: the start and end of the
    episode, s (fixes the time axis, so the frames of one episode line up in a video).
    """

    def __init__(
        self,
        title: str,
        curves: Sequence[str],
        ylabel: str,
        kappa_range: tuple[float, float],
        time_range_s: tuple[float, float],
    ) -> None:
        self.title = title
        self.labels = tuple(curves)
        self.ylabel = ylabel
        self.kappa_range = kappa_range
        self.time_range_s = time_range_s
        self.t_s: list[float] = []
        self.kappa: list[float] = []
        self.values: list[Sequence[float]] = []

    def clear(self) -> None:
        """Forget the episode (at reset)."""
        self.t_s.clear()
        self.kappa.clear()
        self.values.clear()

    def append(self, t_s: float, kappa: float, values: Sequence[float]) -> None:
        """One step: the end of its period (s), its κ and one value per curve."""
        self.t_s.append(float(t_s))
        self.kappa.append(float(kappa))
        self.values.append([float(v) for v in values])

    def frame(self) -> np.ndarray:
        """The episode so far as an RGB image, ``(FRAME_HEIGHT_PX, FRAME_WIDTH_PX, 3)`` uint8."""
        # Imported here: importing the environments stays free of matplotlib. An Agg canvas of
        # its own (no pyplot) leaves the process's backend and figure list alone.
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.ticker import NullFormatter

        fig = Figure(
            figsize=(FRAME_WIDTH_PX / _FRAME_DPI, FRAME_HEIGHT_PX / _FRAME_DPI),
            dpi=_FRAME_DPI,
        )
        # fixed margins: a layout engine would cost more than the drawing itself
        fig.subplots_adjust(left=0.17, right=0.97, bottom=0.14, top=0.92, hspace=0.12)
        canvas = FigureCanvasAgg(fig)
        ax_k, ax_v = fig.subplots(2, 1, sharex=True)
        t = np.asarray(self.t_s)
        lo, hi = self.kappa_range
        t0, t1 = self.time_range_s
        if t.size:  # κ holds over the period that ends at t: stairs over (t_prev, t], from t0
            ax_k.stairs(self.kappa, np.concatenate([[t0], t]), color="C0", lw=1.0)
        ax_k.set_yscale("log")
        ax_k.set_ylim(lo / 2.0, hi * 2.0)
        ax_k.set_ylabel("κ", fontsize=7)
        ax_k.set_title(f"{self.title}  step {t.size}", fontsize=7)
        values = np.asarray(self.values, dtype=float).reshape(t.size, len(self.labels))
        for j, label in enumerate(self.labels):
            ax_v.plot(t, values[:, j], lw=1.0, label=label, color=f"C{j + 1}")
        positive = values[np.isfinite(values) & (values > 0.0)]
        if positive.size:  # a log axis without positive data would warn; keep it linear then
            ax_v.set_yscale("log")
        ax_v.set_ylabel(self.ylabel, fontsize=7)
        ax_v.set_xlabel("t [s]", fontsize=7)
        ax_v.set_xlim(t0, max(t1, t0 + 1.0))  # an equal pair would make matplotlib warn
        if t.size:
            ax_v.legend(fontsize=6, loc="upper right")
        for ax in (ax_k, ax_v):
            ax.tick_params(labelsize=6)
            ax.yaxis.set_minor_formatter(NullFormatter())  # log-axis minor labels only clutter
        canvas.draw()
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()


class TransferAlignmentEnv(gym.Env[np.ndarray, Any]):
    """Choose the filter's process-noise factor every decision period (see module docstring)."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": RENDER_FPS}  # noqa: RUF012

    def __init__(
        self,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str = "likelihood",
        overrides: list[str] | None = None,
        period_s: float = DEFAULT_PERIOD_S,
        observation: str = "v0",
        render_mode: str | None = None,
    ) -> None:
        check_render_mode(render_mode)
        self.render_mode = render_mode
        self._driver = EpisodeDriver(
            1, scenario, action_type, reward, overrides, period_s, observation
        )
        self.episode_steps = self._driver.episode_steps
        self.cfg = self._driver.cfg
        self.actions = self._driver.actions
        self.action_space = self.actions.space
        self.observation_space = self._driver.observation_space
        self._started = False
        self._trace = calibration_trace(self._driver, f"TransferAlignment ({observation})")

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._driver.rngs[0] = self.np_random
        obs = self._driver.reset_env(0)
        self._started = True
        self._trace.clear()
        return obs, {"kappa": 1.0, "diverged": False}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        kappa, _ = self.actions(action)
        out = self._driver.step([action])
        info = {
            "kappa": kappa,
            "diverged": bool(out.terminated[0]),
            "errors": out.errors[0],
            "crlb": out.crlb[0],
            "t_s": float(out.t_s[0]),
        }
        if self.render_mode is not None:  # record only what render() will draw
            self._trace.append(info["t_s"], kappa, calibration_curves(self._driver, out)[0])
        return (
            out.obs[0],
            float(out.reward[0]),
            bool(out.terminated[0]),
            bool(out.truncated[0]),
            info,
        )

    def render(self) -> np.ndarray | None:
        """``render_mode="rgb_array"``: the episode so far as an RGB frame, ``(H, W, 3)`` uint8
        (κ chosen per step; the calibration σ of the filter, the true error and the CRLB).
        ``None`` without a render mode."""
        return self._trace.frame() if self.render_mode is not None else None


CALIBRATION_CURVES = ("filter σ", "true error", "CRLB")
"""The curves of the transfer-alignment frames, all RMS over the nine calibration terms."""


def calibration_trace(driver: EpisodeDriver, title: str) -> EpisodeTrace:
    """The (empty) trace of one transfer-alignment episode of ``driver``'s config."""
    kappas = driver.actions.kappas
    return EpisodeTrace(
        title,
        CALIBRATION_CURVES,
        "calibration RMS [ppm, µrad]",
        (float(kappas.min()), float(kappas.max())),
        (0.0, float(driver.core.t[-1])),
    )


def calibration_curves(driver: EpisodeDriver, out: StepOutput) -> np.ndarray:
    """Every episode's filter σ, true error and CRLB after a step, ``(N, 3)``: RMS over the
    calibration terms, ppm/µrad. The σ is read from the filters' covariance (N × 15 × 15)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged filter: inf/NaN → gaps
        # |diag| only so that a broken (negative) variance of a diverged filter draws, not warns
        var = np.abs(np.diagonal(driver.core.kf.P, axis1=1, axis2=2))
        sigma = np.sqrt(var) / DISPLAY_UNIT
    return np.stack(
        [calibration_rms(sigma), calibration_rms(out.errors), calibration_rms(out.crlb)], axis=1
    )
