"""The figures' scales: round tick values a reader can use (3D normal stress)."""

import numpy as np
import pytest

import admm_dolfinx.io.plotting as plotting

pytest.importorskip("matplotlib")


def test_the_3d_normal_stress_bar_has_round_ticks(tmp_path, monkeypatch):
    """Ticks at round values in 3 significant digits, not the contour levels' raw values."""
    plt = plotting._pyplot()
    figures = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig: figures.append(fig))
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1.0, 1.0, (200, 3))
    lam = 778_123.4 * np.maximum(0.0, 1.0 - 4.0 * (xy[:, 0] ** 2 + xy[:, 1] ** 2))
    path = tmp_path / "normal_stress.png"
    plotting._draw_contact_pressure([("", xy, lam)], 3, path, "t", "x")
    assert path.exists()
    (fig,) = figures
    try:
        bar_axis = fig.axes[-1]
        fig.canvas.draw()
        ticks = bar_axis.get_yticks()
        labels = [label.get_text() for label in bar_axis.get_yticklabels()]
        assert 3 <= len(ticks) <= 8
        for value in ticks[ticks != 0.0]:
            mantissa = abs(value) / 10 ** np.floor(np.log10(abs(value)))
            assert abs(mantissa * 10 - round(mantissa * 10)) < 1e-9  # 1.5e5, not 116719
        assert all(len(text.lstrip("-−")) <= 7 for text in labels), labels
    finally:
        close(fig)
