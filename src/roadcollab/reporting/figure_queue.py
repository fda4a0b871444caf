"""A report's figures drawn at once, or queued and drawn on a few processes at its end.

A report's figures are independent of one another: each is a function of rows the report has already
written. With ``workers`` of 2 or more (``roadcollab reproduce --workers 2``) they are queued and drawn on
the study runner's local process pool (:func:`~roadcollab.experiments.runner.map_runs`) when the report is
done, so the two cores draw six figures in about half the 1.1-1.4 s one core takes (docs/speed.md, "Eighth
pass"); the files are the same. Serially they are drawn at once, in
this process.
"""

from __future__ import annotations

import time
from typing import Callable

from .._validation import check_int
from ..experiments.runner import map_runs

__all__ = ["FigureQueue"]


def _draw(indices: list, queued: list) -> list:
    """A pool worker's share of the queued figures (:func:`~roadcollab.experiments.runner.map_runs` task)."""
    for i in indices:
        plot, args, kwargs = queued[i]
        plot(*args, **kwargs)
    return [None] * len(indices)


class FigureQueue:
    """Draws figures (``queue(plot, *args, **kwargs)``) and adds up the wall time they take (``seconds``).

    Parameters
    ----------
    workers : int, optional
        With 2 or more, figures are queued and drawn by :meth:`finish` on that many processes at most;
        otherwise each is drawn when it is queued.
    """

    def __init__(self, workers: int | None = None) -> None:
        self.workers = None if workers is None else check_int("workers", workers, low=1, high=256)
        self.seconds = 0.0
        self._queued: list[tuple[Callable, tuple, dict]] = []

    def __call__(self, plot: Callable, *args, **kwargs) -> None:
        if self.workers is not None and self.workers >= 2:
            self._queued.append((plot, args, kwargs))
            return
        t0 = time.perf_counter()
        try:
            plot(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - t0

    def finish(self) -> None:
        """Draw the queued figures, on up to ``workers`` processes; a figure's error is raised here.

        The call returns when every drawing process has stopped, also after an error or an interrupt, so
        no figure is written after it (e.g. into a staging folder being removed).
        """
        if not self._queued:
            return
        queued, self._queued = self._queued, []
        t0 = time.perf_counter()
        try:    # the study runner's pool: one figure per chunk; on an error or interrupt it stops its workers
            map_runs(_draw, len(queued), workers=self.workers, chunk_size=1, shared=queued)
        finally:
            self.seconds += time.perf_counter() - t0
