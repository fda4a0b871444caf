"""Row types of the anomaly study's CSVs (the fields of each are its file's columns, in order)
and the road-map example.

``detection.csv`` (:class:`DetectionRow`), ``detection_per_vehicle.csv``
(:class:`VehicleDetectionRow`), ``f1_vs_depth.csv`` (:class:`DepthDetectionRow`),
``f1_vs_noise.csv`` (:class:`NoiseDetectionRow`): a key, the estimator, then the fields of
:class:`~roadcollab.detection.scoring.DetectionScores`. ``fig_anomaly_map.csv``:
:class:`MapRow`, from :meth:`AnomalyMap.to_rows`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar, get_type_hints

from ...detection.scoring import DetectionScores
from ...models.anomaly import Anomaly

__all__ = ["DetectionRow", "VehicleDetectionRow", "DepthDetectionRow", "NoiseDetectionRow", "MapRow", "AnomalyMap"]

_SCORES: list[tuple[str, Any]] = [(f.name, f.type) for f in dataclasses.fields(DetectionScores)]
_RowT = TypeVar("_RowT", bound="_ScoredRow")


if TYPE_CHECKING:   # the fields :func:`_scored_row` appends, as the type checker sees them
    _Scores = DetectionScores
else:
    _Scores = object


class _ScoredRow(_Scores):
    """Base of the scored row types: their keys, then the fields of DetectionScores."""

    if TYPE_CHECKING:
        def __init__(self, **fields: Any) -> None: ...

    @classmethod
    def of(cls: type[_RowT], scores: DetectionScores, **key: Any) -> _RowT:
        """The row of ``scores`` under ``key`` (the row type's key fields by name)."""
        return cls(**key, **dataclasses.asdict(scores))


def _scored_row(keyed: type[_RowT]) -> type[_RowT]:
    """A frozen row type: the key fields annotated on ``keyed``, then the fields of DetectionScores;
    built with ``of``. The class statement only names the keys (and gives the docstring); the type
    is a new dataclass, so the CSV columns stay in that order."""
    keys = list(get_type_hints(keyed).items())
    cls = dataclasses.make_dataclass(keyed.__name__, keys + _SCORES, bases=(_ScoredRow,), frozen=True)
    cls.__module__ = __name__   # pickled by reference to this module's name
    cls.__doc__ = (keyed.__doc__ or "") + "\n\n" + "Build with ``Row.of(scores, **keys)`` (keys: " + \
        ", ".join(k for k, _ in keys) + ")."
    return cls


@_scored_row
class DetectionRow(_ScoredRow):
    """One estimator of ``detection.csv`` (default condition, vehicles 2..V pooled)."""

    estimator: str


@_scored_row
class VehicleDetectionRow(_ScoredRow):
    """One (vehicle, estimator) of ``detection_per_vehicle.csv`` (vehicle 1-based)."""

    vehicle: int
    estimator: str


@_scored_row
class DepthDetectionRow(_ScoredRow):
    """One (depth, estimator) of ``f1_vs_depth.csv`` (every anomaly ``depth_m`` deep, m)."""

    depth_m: float
    estimator: str


@_scored_row
class NoiseDetectionRow(_ScoredRow):
    """One (noise level, estimator) of ``f1_vs_noise.csv`` (m/s^2)."""

    sensor_noise_std: float
    estimator: str


@dataclass(frozen=True)
class MapRow:
    """One anomaly of ``fig_anomaly_map.csv``: a true one or a detection.

    Attributes
    ----------
    source : str
        ``"truth"`` or ``"detected"``.
    estimator : str
        The detecting estimator (empty for the truth).
    position_m : float
        Center, m.
    side, kind : str
        Track (``left``, ``right``, ``both``) and ``pothole`` or ``bump``.
    depth_m : float
        m.
    confidence : float
        1 for the truth.
    """

    source: str
    estimator: str
    position_m: float
    side: str
    kind: str
    depth_m: float
    confidence: float


@dataclass(frozen=True)
class AnomalyMap:
    """Truth and detections of one vehicle on one run (the study's road map).

    Attributes
    ----------
    vehicle, run : int
        1-based.
    region : (float, float)
        The scored stretch, m.
    tolerance : float
        Match tolerance, m.
    truth : tuple of Anomaly
        The road's anomalies.
    detections : dict of str to tuple of Detection
        Per estimator, in the study's order.
    """

    vehicle: int
    run: int
    region: tuple
    tolerance: float
    truth: tuple[Anomaly, ...]
    detections: dict

    def to_rows(self) -> list[MapRow]:
        """Rows of ``fig_anomaly_map.csv``: the true anomalies, then every estimator's detections.

        Returns
        -------
        list of MapRow
        """
        rows = [MapRow("truth", "", a.center, a.side, a.kind, a.depth, 1.0) for a in self.truth]
        return rows + [MapRow("detected", name, d.position, d.side, d.kind, d.depth, d.confidence)
                       for name, dets in self.detections.items() for d in dets]

