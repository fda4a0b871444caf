"""Scoring of anomaly detections against ground truth, one record and pooled.

:func:`match_detections` pairs the detections of one estimate with the true anomalies of its
road and returns a :class:`MatchResult`; :class:`MatchTally` pools the counts and pair
statistics of many such results (over runs and vehicles) and computes precision, recall and F1
from the pooled counts, as the anomaly study and the detector calibration report them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validation import check_positive, check_real
from ..errors import ParameterError
from ..models.anomaly import Anomaly
from .detector import Detection

__all__ = ["DetectionScores", "MatchResult", "MatchTally", "match_detections", "new_false_detections",
           "lost_anomalies"]


def _precision_recall_f1(n_matched: int, n_detected: int, n_true: int) -> tuple[float, float, float]:
    """Precision (1.0 when nothing is detected), recall (1.0 when there is nothing to find) and
    F1 (0.0 when precision + recall = 0) of the counts of matched, detected and true anomalies."""
    precision = n_matched / n_detected if n_detected else 1.0
    recall = n_matched / n_true if n_true else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return precision, recall, f1


def _median_or_nan(values) -> float:
    """Median of a (possibly empty) list of floats; NaN when empty."""
    return float(np.median(values)) if values else float("nan")


@dataclass(frozen=True, eq=False)
class MatchResult:
    """Score of one set of detections against the true anomalies (:func:`match_detections`).

    Attributes
    ----------
    precision : float
        ``n_matched / n_detected``; 1.0 when nothing is detected.
    recall : float
        ``n_matched / n_true``; 1.0 when there is nothing to find.
    f1 : float
        Harmonic mean of precision and recall; 0.0 when both are 0.
    median_position_error_m : float
        Median center distance over the matched pairs, m; NaN if none.
    median_depth_rel_error : float
        Median ``|d_hat - d| / d`` over the matched pairs of the same kind; NaN if none.
    kind_accuracy, side_accuracy : float
        Fraction of the matched pairs whose kind (side) agrees; NaN if no pair.
    n_true, n_detected, n_matched : int
        Counted true anomalies, counted detections (matched plus false positives) and counted
        pairs.
    n_kind_correct, n_side_correct : int
        Matched pairs whose kind (side) agrees.
    position_errors : tuple of float
        Center distance of every counted pair, m.
    depth_rel_errors : tuple of float
        Relative depth error of every counted pair of the same kind.
    pairs : tuple of (int, int)
        ``(detection index, truth index)`` of every counted pair.
    """

    precision: float
    recall: float
    f1: float
    median_position_error_m: float
    median_depth_rel_error: float
    kind_accuracy: float
    side_accuracy: float
    n_true: int
    n_detected: int
    n_matched: int
    n_kind_correct: int
    n_side_correct: int
    position_errors: tuple[float, ...]
    depth_rel_errors: tuple[float, ...]
    pairs: tuple[tuple[int, int], ...]

    def as_dict(self) -> dict:
        """Every field by name, in declaration order; the sequences as lists.

        Returns
        -------
        dict
            ``precision, recall, f1, median_position_error_m, median_depth_rel_error,
            kind_accuracy, side_accuracy, n_true, n_detected, n_matched, n_kind_correct,
            n_side_correct, position_errors, depth_rel_errors, pairs``.
        """
        return {
            "precision": self.precision, "recall": self.recall, "f1": self.f1,
            "median_position_error_m": self.median_position_error_m,
            "median_depth_rel_error": self.median_depth_rel_error,
            "kind_accuracy": self.kind_accuracy, "side_accuracy": self.side_accuracy,
            "n_true": self.n_true, "n_detected": self.n_detected, "n_matched": self.n_matched,
            "n_kind_correct": self.n_kind_correct, "n_side_correct": self.n_side_correct,
            "position_errors": list(self.position_errors), "depth_rel_errors": list(self.depth_rel_errors),
            "pairs": list(self.pairs),
        }


def _center(obj) -> float:
    return float(obj.center if isinstance(obj, Anomaly) else obj.position)


def _check_sequence(name: str, value, typ) -> list:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise ParameterError(f"{name} must be a sequence of {typ.__name__}, got {type(value).__name__}")
    items = list(value)
    for i, item in enumerate(items):
        if not isinstance(item, typ):
            raise ParameterError(f"{name}[{i}] must be a {typ.__name__}, got {type(item).__name__}")
    return items


def _check_region(region) -> tuple[float, float]:
    """``(start_m, end_m)`` of a scored region; the whole line for None."""
    if region is None:
        return -math.inf, math.inf
    if not isinstance(region, (tuple, list)) or len(region) != 2:
        raise ParameterError(f"region must be a (start_m, end_m) pair or None, got {region!r}")
    lo, hi = check_real("region[0]", region[0]), check_real("region[1]", region[1])
    if hi < lo:
        raise ParameterError(f"region must have start_m <= end_m, got ({lo:g}, {hi:g})")
    return lo, hi


def _assign(dets: list[Detection], trs: list[Anomaly], dc: np.ndarray, tc: np.ndarray,
            tolerance: float) -> list[tuple[int, int]]:
    """One-to-one compatible pairs ``(detection index, truth index)``: the most pairs and, among
    those, the smallest summed center distance (Hungarian algorithm)."""
    if not (dets and trs):
        return []
    dist = np.abs(dc[:, None] - tc[None, :])
    compat = np.array([[bool(set(d.tracks) & set(a.tracks)) for a in trs] for d in dets])
    ok = compat & (dist <= tolerance)
    if not ok.any():
        return []
    # Infeasible pairs cost more than all feasible ones together: the optimum has the
    # most feasible pairs and, among those, the smallest summed distance.
    big = tolerance * (min(len(dets), len(trs)) + 1) + 1.0
    rows, cols = linear_sum_assignment(np.where(ok, dist, big))
    return [(int(i), int(k)) for i, k in zip(rows, cols) if ok[i, k]]


def match_detections(detections, truth, *, tolerance=1.0, region=None) -> MatchResult:
    """Score detections against ground-truth anomalies.

    Matching: a detection and a true anomaly are *compatible* when their centers (``Detection.
    position`` vs ``Anomaly.center``) are within ``tolerance`` m and their sides share a track
    (``"both"`` is compatible with ``"left"``, ``"right"`` and ``"both"``; ``"left"`` is not
    compatible with ``"right"``). Kinds need not agree; ``kind_accuracy`` and ``side_accuracy``
    report agreement over the matched pairs. The one-to-one matching maximises the number of
    pairs and, among those, minimises the summed center distance (Hungarian algorithm).

    Region: with ``region=(start_m, end_m)`` the matching is done over all inputs, then a true
    anomaly counts iff its center is in the region, a matched pair counts iff its true anomaly
    counts, and an unmatched detection counts (as a false positive) iff its center is in the
    region; a detection matched to a true anomaly outside the region is ignored. So nothing
    just across the region's edge is penalised twice.

    Parameters
    ----------
    detections : sequence of Detection
    truth : sequence of roadcollab.models.road.Anomaly
    tolerance : float
        Maximum center distance of a match, m, > 0.
    region : (float, float) or None
        Scored stretch of road, m.

    Returns
    -------
    MatchResult
        Counts, precision, recall, F1, position and depth errors and agreement of the counted
        pairs (see its attributes; :meth:`MatchResult.as_dict` for a plain dict).
    """
    dets = _check_sequence("detections", detections, Detection)
    trs = _check_sequence("truth", truth, Anomaly)
    tolerance = check_positive("tolerance", tolerance)
    lo, hi = _check_region(region)
    dc = np.array([_center(d) for d in dets])
    tc = np.array([_center(a) for a in trs])
    pairs = _assign(dets, trs, dc, tc, tolerance)
    t_in = (tc >= lo) & (tc <= hi) if trs else np.zeros(0, bool)
    d_in = (dc >= lo) & (dc <= hi) if dets else np.zeros(0, bool)
    counted = [(i, k) for i, k in pairs if t_in[k]]
    matched_dets = {i for i, _ in pairs}
    false_pos = sum(1 for i in range(len(dets)) if i not in matched_dets and d_in[i])
    n_true = int(t_in.sum())
    n_matched = len(counted)
    n_detected = n_matched + false_pos
    precision, recall, f1 = _precision_recall_f1(n_matched, n_detected, n_true)
    errs = [abs(dc[i] - tc[k]) for i, k in counted]
    kind_ok = [dets[i].kind == trs[k].kind for i, k in counted]
    side_ok = [dets[i].side == trs[k].side for i, k in counted]
    depth_rel = [abs(dets[i].depth - trs[k].depth) / trs[k].depth for i, k in counted if dets[i].kind == trs[k].kind]
    nan = float("nan")
    return MatchResult(
        precision=float(precision), recall=float(recall), f1=float(f1),
        median_position_error_m=_median_or_nan(errs), median_depth_rel_error=_median_or_nan(depth_rel),
        kind_accuracy=float(np.mean(kind_ok)) if kind_ok else nan,
        side_accuracy=float(np.mean(side_ok)) if side_ok else nan,
        n_true=n_true, n_detected=int(n_detected), n_matched=n_matched,
        n_kind_correct=int(sum(kind_ok)), n_side_correct=int(sum(side_ok)),
        position_errors=tuple(float(e) for e in errs), depth_rel_errors=tuple(float(e) for e in depth_rel),
        pairs=tuple(counted))


@dataclass(frozen=True)
class DetectionScores:
    """Pooled detection scores of one estimator (the score columns of the anomaly study's CSVs).

    Attributes
    ----------
    precision, recall, f1 : float
        From the pooled counts.
    median_position_error_m : float
        Median center error of the matched pairs, m (NaN without pairs).
    median_depth_rel_error : float
        Median relative depth error of the matched pairs (NaN without pairs).
    kind_accuracy, side_accuracy : float
        Share of matched pairs of the right kind / on the right track (NaN without pairs).
    n_true, n_detected, n_matched : int
        Pooled counts.
    """

    precision: float
    recall: float
    f1: float
    median_position_error_m: float
    median_depth_rel_error: float
    kind_accuracy: float
    side_accuracy: float
    n_true: int
    n_detected: int
    n_matched: int


class MatchTally:
    """Pooled counts and pair statistics of many :class:`MatchResult` (e.g. one estimator over
    runs and vehicles); precision, recall and F1 come from the pooled counts."""

    __slots__ = ("n_true", "n_detected", "n_matched", "n_kind", "n_side", "pos_err", "depth_err")

    def __init__(self) -> None:
        self.n_true = self.n_detected = self.n_matched = self.n_kind = self.n_side = 0
        self.pos_err: list[float] = []
        self.depth_err: list[float] = []

    def add(self, m: MatchResult) -> None:
        """Add the counts and pairs of one match result.

        Parameters
        ----------
        m : MatchResult
        """
        self.n_true += m.n_true
        self.n_detected += m.n_detected
        self.n_matched += m.n_matched
        self.n_kind += m.n_kind_correct
        self.n_side += m.n_side_correct
        self.pos_err += m.position_errors
        self.depth_err += m.depth_rel_errors

    def merge(self, other: "MatchTally") -> None:
        """Add the counts and pairs of another tally (e.g. one pooled on a worker).

        Parameters
        ----------
        other : MatchTally
        """
        self.n_true += other.n_true
        self.n_detected += other.n_detected
        self.n_matched += other.n_matched
        self.n_kind += other.n_kind
        self.n_side += other.n_side
        self.pos_err += other.pos_err
        self.depth_err += other.depth_err

    def scores(self) -> DetectionScores:
        """The pooled scores.

        Returns
        -------
        DetectionScores
        """
        p, r, f1 = _precision_recall_f1(self.n_matched, self.n_detected, self.n_true)
        nan = float("nan")
        return DetectionScores(
            precision=p, recall=r, f1=f1, median_position_error_m=_median_or_nan(self.pos_err),
            median_depth_rel_error=_median_or_nan(self.depth_err),
            kind_accuracy=self.n_kind / self.n_matched if self.n_matched else nan,
            side_accuracy=self.n_side / self.n_matched if self.n_matched else nan,
            n_true=self.n_true, n_detected=self.n_detected, n_matched=self.n_matched)

    def row(self) -> dict:
        """The pooled scores as a dict (:meth:`scores`, keys in column order).

        Returns
        -------
        dict
            The fields of :class:`DetectionScores`.
        """
        return asdict(self.scores())


def new_false_detections(attacked, honest, truth, *, tolerance: float = 1.0) -> int:
    """Detections under attack that match neither a true anomaly nor an honest detection.

    Parameters
    ----------
    attacked, honest : sequence of Detection
        Detections of the same estimator on the same record, with and without the attack.
    truth : sequence of Anomaly
        The true anomalies.
    tolerance : float
        Largest center distance of a match (same kind), m.

    Returns
    -------
    int
    """
    tolerance = check_positive("tolerance", tolerance)
    known = [(a.kind, a.center) for a in truth] + [(h.kind, h.position) for h in honest]
    return sum(not any(d.kind == k and abs(d.position - c) <= tolerance for k, c in known) for d in attacked)


def lost_anomalies(attacked, honest, truth, *, tolerance: float = 1.0) -> int:
    """True anomalies the honest detections found and the attacked ones do not.

    Parameters
    ----------
    attacked, honest : sequence of Detection
        Detections of the same estimator on the same record, with and without the attack.
    truth : sequence of Anomaly
        The true anomalies.
    tolerance : float
        Largest center distance of a match, m (as :func:`match_detections`).

    Returns
    -------
    int
    """
    found = {t for _, t in match_detections(honest, truth, tolerance=tolerance).pairs}
    kept = {t for _, t in match_detections(attacked, truth, tolerance=tolerance).pairs}
    return len(found - kept)

