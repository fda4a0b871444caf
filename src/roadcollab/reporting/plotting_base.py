"""What every figure module shares: the Agg backend, :func:`save_figure` and legends that hide no data.

Imported by :mod:`~roadcollab.reporting.plotting` and the ``plotting_*`` modules, the only
modules that import matplotlib.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.layout_engine import PlaceHolderLayoutEngine  # noqa: E402

__all__ = ["plt", "save_figure", "legend_outside"]


def save_figure(fig, path, *, dpi: float = 120, tight: bool = True) -> Path:
    """Lay out ``fig``, write it to ``path`` (120 dpi by default) and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The finished figure.
    path : str or Path
        Output image (format from the suffix).
    dpi : float
        Resolution, dots per inch.
    tight : bool
        Apply ``tight_layout`` first (False for figures laid out by a layout engine of their own).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    if tight:
        fig.tight_layout()
        # tight_layout leaves a placeholder layout engine behind, and savefig then draws the whole figure
        # once more without rendering before the real draw (which a layout engine acting at draw time
        # needs). Nothing is left to lay out: without it, the same bytes and one draw fewer (docs/speed.md).
        if isinstance(fig.get_layout_engine(), PlaceHolderLayoutEngine):
            fig.set_layout_engine(None)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def legend_outside(ax, *, fontsize: float = 8, **kw):
    """A legend to the right of ``ax``, outside the axes, so it covers no data.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes whose labelled artists are listed.
    fontsize : float
        Points.
    **kw
        Passed to ``ax.legend`` (e.g. ``handles``, ``title``).

    Returns
    -------
    matplotlib.legend.Legend
    """
    return ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=fontsize, **kw)
