"""Plot helpers shared by the reports: a non-interactive backend and figures rendered to bytes
(so a report can write every file atomically once everything is computed)."""

from __future__ import annotations

import io
import os
from functools import cache

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

PLACEHOLDER_ENV = "QKF_PLACEHOLDER_FIGURES"
"""When set (non-empty), :func:`figure_png` builds each figure (its plotting code runs) but
returns a 1 × 1 PNG instead of rendering it: rendering is matplotlib's layout of the ticks and
labels, 0.3–5 s a figure, most of a short ``qkf bench``. The test suite sets it for the
commands it starts in other processes (tests/conftest.py); every file is still written."""


@cache
def placeholder_png() -> bytes:
    """A valid 1 × 1 PNG: what a figure is written as under :data:`PLACEHOLDER_ENV`."""
    buf = io.BytesIO()
    plt.imsave(buf, np.zeros((1, 1, 4)), format="png")
    return buf.getvalue()


def figure_png(fig: Figure, dpi: int = 120) -> bytes:
    """The figure as PNG bytes; the figure is closed."""
    if os.environ.get(PLACEHOLDER_ENV):
        plt.close(fig)
        return placeholder_png()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()


__all__ = ["PLACEHOLDER_ENV", "Figure", "figure_png", "placeholder_png", "plt"]
