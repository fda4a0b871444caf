"""Result of the anomaly detector's calibration: the scores of every grid point and the best one."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .config import ESTIMATORS
from .calibration_config import AnomalyCalibrationConfig

__all__ = ["CalibrationPoint", "CalibrationRow", "AnomalyCalibrationResult", "score_column"]

#: The scores of every condition and estimator in ``calibration.csv``, in column order.
_METRICS = ("f1", "precision", "recall")


def score_column(metric: str, condition: str, estimator: str) -> str:
    """The ``calibration.csv`` column of one score.

    Parameters
    ----------
    metric : str
        ``"f1"``, ``"precision"`` or ``"recall"``.
    condition, estimator : str
        A condition of the configuration and an estimator.

    Returns
    -------
    str
        ``<metric>_<condition>_<estimator>``.
    """
    return f"{metric}_{condition}_{estimator}"


@dataclass(frozen=True)
class CalibrationRow:
    """One grid point of ``calibration.csv``: its leading columns, then its scores.

    The score columns depend on the configured conditions, so they are not fields: ``scores`` holds
    them and :meth:`AnomalyCalibrationResult.columns` keeps the file's column list.

    Attributes
    ----------
    snr_threshold : float
        The detector's threshold on the matched filter's SNR (dimensionless).
    min_depth_m : float
        The detector's depth floor, m.
    objective : float
        Mean F1 of :data:`OBJECTIVE_ESTIMATORS` over the conditions (dimensionless).
    gap_to_best : float
        ``J(best) - J(point)`` (mean F1).
    gap_se : float
        Its paired standard error over the seeds; NaN for one seed.
    scores : dict
        ``{score_column(metric, condition, estimator): value}`` of every metric (f1, precision,
        recall), condition and estimator, in column order (dimensionless).
    """

    snr_threshold: float
    min_depth_m: float
    objective: float
    gap_to_best: float
    gap_se: float
    scores: dict[str, float]

    def record(self) -> dict:
        """The row as ``calibration.csv`` writes it.

        Returns
        -------
        dict
            The leading fields, then ``scores``, keyed by column in column order.
        """
        return {"snr_threshold": self.snr_threshold, "min_depth_m": self.min_depth_m, "objective": self.objective,
                "gap_to_best": self.gap_to_best, "gap_se": self.gap_se, **self.scores}


#: The leading columns of ``calibration.csv`` (the fields of CalibrationRow before its scores).
_POINT_COLUMNS = tuple(f.name for f in fields(CalibrationRow) if f.name != "scores")


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

    def columns(self) -> list[str]:
        """The columns of ``calibration.csv`` (they depend on the configured conditions).

        Returns
        -------
        list of str
            ``snr_threshold, min_depth_m, objective, gap_to_best, gap_se``, then
            :func:`score_column` of every metric (f1, precision, recall), condition and estimator.
        """
        return list(_POINT_COLUMNS) + [score_column(m, c, e) for m in _METRICS for c in self.config.conditions
                                       for e in ESTIMATORS]

    def to_rows(self) -> list[CalibrationRow]:
        """One row per grid point for ``calibration.csv`` (:meth:`CalibrationRow.record` in :meth:`columns`).

        Returns
        -------
        list of CalibrationRow
            In grid order.
        """
        rows = []
        for p in self.points:
            gap, se = self.gap(p)
            scores = {score_column(m, c, e): p.scores[c, e][m]
                      for m in _METRICS for c in self.config.conditions for e in ESTIMATORS}
            rows.append(CalibrationRow(p.snr_threshold, p.min_depth, p.objective, gap, se, scores))
        return rows
