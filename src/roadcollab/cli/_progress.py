"""Progress bars of the long commands (rich, on stderr)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable, Sequence, TypeVar

if TYPE_CHECKING:
    from rich.progress import Progress

__all__ = ["progress", "progress_bars", "run_with_progress"]

#: What a subcommand's work returns.
_T = TypeVar("_T")


def progress(total: int, description: str) -> tuple[Progress, Callable[[int], None]]:
    """A rich progress bar (on stderr) and a callback that advances it.

    Parameters
    ----------
    total : int
        Number of steps.
    description : str
        Label left of the bar.

    Returns
    -------
    prog : rich.progress.Progress
        Use as a context manager around the work.
    advance : callable
        ``advance(done)`` sets the number of completed steps.
    """
    prog, (cb,) = progress_bars([(total, description)])
    return prog, cb


def progress_bars(bars: Sequence[tuple[int, str]]) -> tuple[Progress, list[Callable[[int], None]]]:
    """Rich progress bars (on stderr), one per ``(total, description)``, and a callback per bar.

    Parameters
    ----------
    bars : sequence of (int, str)
        Number of steps and label of each bar.

    Returns
    -------
    prog : rich.progress.Progress
        Use as a context manager around the work.
    advance : list of callable
        ``advance[k](done)`` sets the number of completed steps of bar ``k``.
    """
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    prog = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=Console(stderr=True), transient=False)
    tasks = [prog.add_task(description, total=total) for total, description in bars]

    def advance(task) -> Callable[[int], None]:
        return lambda done: prog.update(task, completed=done)

    return prog, [advance(task) for task in tasks]


def run_with_progress(total: int, description: str, work: Callable[[Callable[[int], None]], _T]
                      ) -> tuple[_T, float]:
    """Run ``work(advance)`` under a progress bar (:func:`progress`).

    Parameters
    ----------
    total : int
        Number of steps the bar counts.
    description : str
        Label left of the bar.
    work : callable
        Called once with the bar's ``advance(done)`` callback; returns the result.

    Returns
    -------
    result
        What ``work`` returned.
    elapsed : float
        Wall time of ``work``, s.
    """
    prog, cb = progress(total, description)
    t0 = time.perf_counter()
    with prog:
        result = work(cb)
    return result, time.perf_counter() - t0
