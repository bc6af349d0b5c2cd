"""qkf.core.plotting: figures to PNG bytes, and placeholders where the environment asks."""

from __future__ import annotations

import io

import matplotlib.pyplot as plt
import pytest
from PIL import Image

from qkf.core.plotting import PLACEHOLDER_ENV, figure_png, placeholder_png


@pytest.mark.figures  # renders for real where the variable is empty
def test_a_placeholder_only_where_the_environment_asks(monkeypatch: pytest.MonkeyPatch) -> None:
    def drawn() -> plt.Figure:
        fig, ax = plt.subplots(figsize=(2, 1))
        ax.plot([0, 1], [1, 0])
        return fig

    monkeypatch.setenv(PLACEHOLDER_ENV, "")
    fig = drawn()
    real = Image.open(io.BytesIO(figure_png(fig, dpi=50)))
    assert real.size == (100, 50) and not plt.fignum_exists(fig.number)
    monkeypatch.setenv(PLACEHOLDER_ENV, "1")
    fig = drawn()
    png = figure_png(fig)
    assert png == placeholder_png() and not plt.fignum_exists(fig.number)
    assert Image.open(io.BytesIO(png)).size == (1, 1)
