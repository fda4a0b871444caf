"""Wall-clock timing shared by the cryptographic baselines."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from ..._validation import check_int
from ...errors import ParameterError

__all__ = ["median_ms"]


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    """Median wall-clock time of ``repeats`` calls of ``fn()``, ms.

    Each call is timed on its own with :func:`time.perf_counter`; the return values are
    discarded. The median is robust against the occasional garbage collection or scheduler
    pause.

    Parameters
    ----------
    fn : callable
        Called without arguments.
    repeats : int
        Number of timed calls (>= 1). There is no warm-up call.

    Returns
    -------
    float
        Median duration of one call, milliseconds.
    """
    if not callable(fn):
        raise ParameterError(f"fn must be callable, got {type(fn).__name__}")
    repeats = check_int("repeats", repeats, low=1)
    times = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - t0
    return float(np.median(times) * 1e3)
