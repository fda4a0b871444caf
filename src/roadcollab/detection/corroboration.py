"""Fleet anomaly map: a detection stands only if several vehicles saw it on their own.

A detection in the fused estimate is reported when at least ``min_votes`` *different* vehicles
detected an anomaly of the same kind, on a shared track, within ``tolerance`` metres, each in
its own estimate. With at most ``f`` lying vehicles, ``min_votes = f + 1`` guarantees that every
reported anomaly was seen by at least one honest vehicle; the default 3 tolerates two colluding
vehicles. The price is recall on anomalies that few honest vehicles detect: an anomaly is
lost if fewer than ``min_votes`` of the honest vehicles detect it (with per-vehicle recall
``r`` and ``h`` honest vehicles, a binomial tail; measured in ``roadcollab attack``'s
``poisoning.csv``, column ``real_anomalies_lost``).
"""

from __future__ import annotations

from typing import Sequence

from .._validation import check_int, check_positive
from ..errors import ParameterError
from .detector import Detection

__all__ = ["DEFAULT_MIN_VOTES", "corroborate", "votes"]

#: Independent vehicles that must see an anomaly before the fleet map reports it.
DEFAULT_MIN_VOTES = 3


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
