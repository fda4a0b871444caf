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

from ...detection.scoring import DetectionScores
from ...models.anomaly import Anomaly

__all__ = ["DetectionRow", "VehicleDetectionRow", "DepthDetectionRow", "NoiseDetectionRow", "MapRow", "AnomalyMap"]

_SCORES = [(f.name, f.type) for f in dataclasses.fields(DetectionScores)]


def _scored_row(name: str, keys: list[tuple[str, type]], doc: str) -> type:
    """A frozen row type: ``keys``, then the fields of DetectionScores; built with ``of``."""
    def of(cls, scores: DetectionScores, **key):
        return cls(**key, **dataclasses.asdict(scores))

    cls = dataclasses.make_dataclass(name, keys + _SCORES, frozen=True, namespace={"of": classmethod(of)})
    cls.__module__ = __name__   # pickled by reference to this module's name
    cls.__doc__ = doc + "\n\n" + "Build with ``Row.of(scores, **keys)`` (keys: " + \
        ", ".join(k for k, _ in keys) + ")."
    return cls


DetectionRow = _scored_row("DetectionRow", [("estimator", str)],
                           "One estimator of ``detection.csv`` (default condition, vehicles 2..V pooled).")
VehicleDetectionRow = _scored_row("VehicleDetectionRow", [("vehicle", int), ("estimator", str)],
                                  "One (vehicle, estimator) of ``detection_per_vehicle.csv`` (vehicle 1-based).")
DepthDetectionRow = _scored_row("DepthDetectionRow", [("depth_m", float), ("estimator", str)],
                                "One (depth, estimator) of ``f1_vs_depth.csv`` (every anomaly ``depth_m`` deep, m).")
NoiseDetectionRow = _scored_row("NoiseDetectionRow", [("sensor_noise_std", float), ("estimator", str)],
                                "One (noise level, estimator) of ``f1_vs_noise.csv`` (m/s^2).")


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

