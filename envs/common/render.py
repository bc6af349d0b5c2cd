"""Rendering shared by the qkf environments (docs/environment.md, "Rendering").

``render_mode`` is ``None`` (nothing recorded, ``render()`` returns ``None``) or
``"rgb_array"``: each step appends a few numbers to an :class:`EpisodeTrace`, and ``render()``
draws the episode so far into an RGB frame (``FRAME_HEIGHT_PX × FRAME_WIDTH_PX × 3`` uint8).
Nothing is drawn in ``step``: a frame costs about 0.2 s, so it is drawn only when asked for.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

RENDER_MODES: tuple[str, ...] = ("rgb_array",)
"""The render modes of the qkf environments besides ``None`` (Gymnasium's ``metadata``)."""
RENDER_FPS = 10
"""Frames per second of a recorded video (Gymnasium's ``metadata["render_fps"]``): one frame
per decision period, so a 3600-s episode of 10-s periods plays in 36 s. A display rate, not a
physical one."""
FRAME_HEIGHT_PX = 240
FRAME_WIDTH_PX = 320
_FRAME_DPI = 80  # figure inches × dpi = pixels; small fonts stay legible at 320 × 240


def check_render_mode(render_mode: str | None) -> None:
    """Accept ``None`` and the modes of :data:`RENDER_MODES`; anything else is a ``ValueError``
    raised at construction, before any work is done."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        modes = ", ".join(repr(m) for m in (None, *RENDER_MODES))
        raise ValueError(f"render_mode {render_mode!r} is not supported; use one of {modes}")


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
