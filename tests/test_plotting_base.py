"""save_figure: laid out once, drawn once, the bytes of matplotlib's own tight layout and save."""

import numpy as np
from matplotlib.figure import Figure

from roadcollab.reporting.plotting_base import plt, save_figure


def _figure():
    fig, axes = plt.subplots(2, 1, figsize=(6, 4))
    x = np.linspace(0.0, 20.0, 4000)
    for k, ax in enumerate(axes):
        ax.plot(x, np.sin((k + 1) * x), label=f"track {k}")
        ax.set_ylabel("w (m/s)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return fig


def test_a_tight_figure_is_drawn_once_with_the_same_bytes(tmp_path, monkeypatch):
    # tight_layout leaves a placeholder layout engine, for which savefig drew the figure twice (once without
    # rendering); save_figure drops it: one draw, and the file of tight_layout() + savefig() byte for byte.
    ref = _figure()
    ref.tight_layout()
    ref.savefig(tmp_path / "ref.png", dpi=120)
    draws = []
    real = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda self, renderer: (draws.append(1), real(self, renderer))[1])
    save_figure(_figure(), tmp_path / "ours.png")
    assert len(draws) == 1
    assert (tmp_path / "ours.png").read_bytes() == (tmp_path / "ref.png").read_bytes()
