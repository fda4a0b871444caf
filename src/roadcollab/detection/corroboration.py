"""Fleet anomaly map: a detection stands only if several vehicles saw it on their own.

A detection in the fused estimate is reported when at least ``min_votes`` *different* vehicles
detected an anomaly of the same kind, on a shared track, within ``tolerance`` metres, each in
its own estimate. With at most ``f`` lying vehicles, ``min_votes = f + 1`` guarantees that every
reported anomaly was seen by at least one honest vehicle, and ``min_votes <= n - f`` that the
honest vehicles alone can still report it when the liars withhold their votes;
:func:`min_votes_for` gives ``f + 1`` for the largest ``f`` with ``2 f + 1 <= n`` (the fusion node's
breakdown, ``floor((n - 1) / 2)``). The fixed default 3 (``f = 2``) holds only for ``n >= 5``: with
``n = 3`` it equals the fleet and one silent liar erases every anomaly (issue 20). The price is recall on anomalies that few honest vehicles detect: an anomaly is
lost if fewer than ``min_votes`` of the honest vehicles detect it (with per-vehicle recall
``r`` and ``h`` honest vehicles, a binomial tail; measured in ``roadcollab attack``'s
``poisoning.csv``, column ``real_anomalies_lost``).
"""

from __future__ import annotations

from typing import Sequence

from .._validation import check_int, check_positive
from ..errors import ParameterError
from .detector import Detection

__all__ = ["DEFAULT_MIN_VOTES", "confirmed_by_own", "corroborate", "min_votes_for", "votes"]

#: Independent vehicles that must see an anomaly before the fleet map reports it.
DEFAULT_MIN_VOTES = 3


def min_votes_for(n: int, tolerated: int | None = None) -> int:
    """Votes a report needs in a fleet of ``n`` with at most ``tolerated`` liars: ``f + 1``.

    Parameters
    ----------
    n : int
        Vehicles that report (``n >= 1``).
    tolerated : int, optional
        ``f``, the liars to withstand; default ``floor((n - 1) / 2)``, the most for which
        ``f + 1 <= n - f``.

    Returns
    -------
    int
        ``f + 1``: more than the liars can cast, no more than the honest vehicles can.

    Raises
    ------
    ParameterError
        If ``f + 1 > n - f`` (the liars could then erase every anomaly by staying silent).

    Examples
    --------
    >>> [min_votes_for(n) for n in (1, 3, 5, 7, 10)]
    [1, 2, 3, 4, 5]
    """
    n = check_int("n", n, low=1)
    f = (n - 1) // 2 if tolerated is None else check_int("tolerated", tolerated, low=0)
    if f + 1 > n - f:
        raise ParameterError(f"tolerated must satisfy 2 * tolerated + 1 <= n = {n} (f + 1 votes from the "
                             f"n - f honest vehicles), got {f}")
    return f + 1


def _agrees(a: Detection, b: Detection, tolerance: float) -> bool:
    return (a.kind == b.kind and abs(a.position - b.position) <= tolerance
            and bool(set(a.tracks) & set(b.tracks)))


def votes(detection: Detection, per_vehicle: Sequence[Sequence[Detection]], *, tolerance: float = 1.0) -> int:
    """Number of vehicles whose own detections include one that agrees with ``detection``.

    Parameters
    ----------
    detection : Detection
        A detection in the fused estimate.
    per_vehicle : sequence of sequence of Detection
        Each vehicle's own detections (one entry per vehicle).
    tolerance : float
        Largest distance between agreeing centers, m.

    Returns
    -------
    int
    """
    return sum(any(_agrees(detection, e, tolerance) for e in dets) for dets in per_vehicle)


def corroborate(detections: Sequence[Detection], per_vehicle: Sequence[Sequence[Detection]], *,
                min_votes: int = DEFAULT_MIN_VOTES, tolerance: float = 1.0) -> list[Detection]:
    """The fused detections that at least ``min_votes`` vehicles saw on their own.

    Parameters
    ----------
    detections : sequence of Detection
        Detections in the fused estimate.
    per_vehicle : sequence of sequence of Detection
        Each vehicle's own detections, one entry per vehicle.
    min_votes : int
        Vehicles needed (``f + 1`` against ``f`` liars).
    tolerance : float
        Largest distance between agreeing centers, m.

    Returns
    -------
    list of Detection
        The corroborated subset, in the input order.
    """
    min_votes = check_int("min_votes", min_votes, low=1)
    tolerance = check_positive("tolerance", tolerance)
    for i, dets in enumerate(per_vehicle):
        if not all(isinstance(d, Detection) for d in dets):
            raise ParameterError(f"per_vehicle[{i}] must hold Detection objects")
    if min_votes > len(per_vehicle):
        raise ParameterError(f"min_votes must be at most the number of vehicles ({len(per_vehicle)}), "
                             f"got {min_votes}")
    return [d for d in detections if votes(d, per_vehicle, tolerance=tolerance) >= min_votes]


def confirmed_by_own(detections: Sequence[Detection], own: Sequence[Detection], *,
                     tolerance: float = 1.0) -> list[Detection]:
    """The detections of a message-aided estimate that the receiver's own data supports.

    A received message may move a receiver's estimate (within its guard's bound); an anomaly it reports
    must also show in an estimate made from its own record alone (its observer, its own inversion): a
    lie cannot plant an anomaly the receiver reports. The price is recall where only the message sees one
    (measured in ``docs/security-receivers.md``).

    Parameters
    ----------
    detections : sequence of Detection
        Detections in the estimate that used the message.
    own : sequence of Detection
        Detections in the receiver's own estimates (without the message).
    tolerance : float
        Largest distance between agreeing centers, m.

    Returns
    -------
    list of Detection
        The confirmed subset, in the input order.
    """
    tolerance = check_positive("tolerance", tolerance)
    if not all(isinstance(d, Detection) for d in list(detections) + list(own)):
        raise ParameterError("detections and own must hold Detection objects")
    return [d for d in detections if any(_agrees(d, e, tolerance) for e in own)]
