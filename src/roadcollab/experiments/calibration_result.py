"""Result of the anomaly detector's calibration: the scores of every grid point and the best one."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .anomaly_config import ESTIMATORS
from .calibration_config import AnomalyCalibrationConfig

__all__ = ["CalibrationPoint", "AnomalyCalibrationResult"]


@dataclass(frozen=True, eq=False)
class CalibrationPoint:
    """Scores of one grid point, pooled over seeds, runs and vehicles 2..V.

    Attributes
    ----------
    snr_threshold : float
    min_depth : float
        m.
    objective : float
        Mean F1 of :data:`OBJECTIVE_ESTIMATORS` over the conditions.
    seed_objectives : tuple of float
        The same objective from each training seed's pooled counts (in ``config.seeds`` order).
    scores : dict
        ``(condition, estimator) -> dict`` with ``precision, recall, f1, n_true, n_detected,
        n_matched``.
    """

    snr_threshold: float
    min_depth: float
    objective: float
    seed_objectives: tuple[float, ...]
    scores: dict


@dataclass(frozen=True, eq=False)
class AnomalyCalibrationResult:
    """The grid of a calibration and its best point.

    Attributes
    ----------
    config : AnomalyCalibrationConfig
    points : tuple of CalibrationPoint
        In grid order (``snr_threshold``-major).
    elapsed_s : float
        Wall-clock time, s.
    """

    config: AnomalyCalibrationConfig
    points: tuple[CalibrationPoint, ...]
    elapsed_s: float

    @property
    def best(self) -> CalibrationPoint:
        """The point of largest objective (the first in grid order on ties)."""
        return self.points[int(np.argmax([p.objective for p in self.points]))]

    @property
    def reference(self) -> CalibrationPoint | None:
        """The grid point of ``config.detector``'s threshold and depth floor, if on the grid."""
        det = self.config.detector
        for p in self.points:
            if p.snr_threshold == det.snr_threshold and p.min_depth == det.min_depth:
                return p
        return None

    def gap(self, point: CalibrationPoint) -> tuple[float, float]:
        """Objective gap of a point to the best point.

        Parameters
        ----------
        point : CalibrationPoint

        Returns
        -------
        gap : float
            ``J(best) - J(point)`` (mean F1, dimensionless).
        se : float
            Its paired standard error over the seeds; NaN for one seed.
        """
        d = np.subtract(self.best.seed_objectives, point.seed_objectives)
        se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else float("nan")
        return self.best.objective - point.objective, se

    def to_rows(self) -> list[dict]:
        """One dict per grid point for ``calibration.csv``: ``snr_threshold, min_depth_m,
        objective, gap_to_best, gap_se``, then ``f1_<condition>_<estimator>`` for every condition
        and estimator, then the same for ``precision_`` and ``recall_``."""
        rows = []
        for p in self.points:
            gap, se = self.gap(p)
            row = {"snr_threshold": p.snr_threshold, "min_depth_m": p.min_depth, "objective": p.objective,
                   "gap_to_best": gap, "gap_se": se}
            for metric in ("f1", "precision", "recall"):
                for c in self.config.conditions:
                    for e in ESTIMATORS:
                        row[f"{metric}_{c}_{e}"] = p.scores[c, e][metric]
            rows.append(row)
        return rows
