"""Calibration of the anomaly detector's threshold and depth floor on *training* seeds.

The detector's ``snr_threshold`` and ``min_depth`` (:class:`roadcollab.detection.detector.DetectorSpec`)
are chosen by a grid search on training runs that the evaluation (``roadcollab anomalies``,
seed 0) never sees; this module ships that procedure as ``roadcollab calibrate-anomalies``.

Procedure
---------
For every training root seed ``s`` (default 1000..1004), ``np.random.SeedSequence(s).spawn(2)``
gives the fleet and the runs' parent, exactly as in
:func:`roadcollab.experiments.anomaly_study.run_anomaly_study` (the same private helpers build the
pipelines and the per-run seeds, so training seed ``s`` with ``runs_per_seed`` runs is the study
with root seed ``s`` and ``n_runs = runs_per_seed``). Run ``i`` of seed ``s`` is driven under
three road conditions with common random numbers: the default road (anomalies 2.5-10 cm deep or
high), every anomaly 2 cm, every anomaly 3 cm (``condition_depths``). The three estimates of
every vehicle (``observer_only``, ``collaborative``, ``fused``) are computed once per run and
condition; only the detection and the scoring are repeated per grid point
``(snr_threshold, min_depth)``.

Scoring pools counts over seeds, runs and vehicles 2..V, as the study does (vehicle 1 has no
predecessor). The objective of a grid point is

.. math:: J = \\frac{1}{6} \\sum_{c \\in \\text{conditions}} \\sum_{e \\in \\{\\text{collaborative},
   \\text{fused}\\}} F_1(c, e),

and the best point is the first maximiser in grid order (``snr_threshold``-major). The flatness
of the optimum is reported as the gap ``J(best) - J(g)`` of every point with its paired standard
error over the training seeds (each seed's objective from that seed's pooled counts).

Cost: ``len(seeds) * runs_per_seed`` runs, each ``1 + len(condition_depths)`` calls of
``run_estimates`` (about 0.05 s for 10 vehicles) and ``n_grid * n_conditions * 3 * (V - 1)``
detections (about 2 ms each): 5-9 s per run for the default 30-point grid and 10 vehicles; the
default calibration (40 runs) took about 3 min on 2 workers of the 2-core machine.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .._validation import check_int, check_positive, check_real
from ..detection.detector import DetectorSpec
from ..experiments.anomaly_study import (ESTIMATORS, AnomalyStudyConfig, _check_levels, _condition_pipelines, _fresh,
                            _run_seeds, _score, _Tally)
from ..errors import ParameterError
from ..experiments.reproduction import ExperimentConfig, run_estimates

__all__ = ["EVALUATION_SEEDS", "OBJECTIVE_ESTIMATORS", "AnomalyCalibrationConfig", "CalibrationPoint",
           "AnomalyCalibrationResult", "parse_seeds", "calibrate_anomalies", "write_calibration"]

#: Root seeds of the evaluation (the default ``--seed`` of ``roadcollab anomalies``): refused.
EVALUATION_SEEDS = (0,)

#: Estimates whose F1 enters the objective (attributes of :class:`~roadcollab.experiments.reproduction.RunEstimates`).
OBJECTIVE_ESTIMATORS = ("collaborative", "fused")


def _check_grid(name: str, value, *, low_open: bool) -> tuple[float, ...]:
    if not isinstance(value, (tuple, list)) or len(value) == 0:
        raise ParameterError(f"{name} must be a non-empty tuple of numbers, got {value!r}")
    out = tuple(check_real(f"{name}[{i}]", v, low=0.0, low_open=low_open) for i, v in enumerate(value))
    if len(set(out)) != len(out):
        raise ParameterError(f"{name} must not repeat a value, got {out}")
    return out


@dataclass(frozen=True)
class AnomalyCalibrationConfig:
    """Everything the calibration depends on, the training seeds included.

    Parameters
    ----------
    seeds : tuple of int
        Training root seeds (>= 0, distinct, none of :data:`EVALUATION_SEEDS`).
    runs_per_seed : int
        Roads (runs) per seed.
    experiment : ExperimentConfig
        Fleet, road and sensors of the default condition (its ``n_runs`` is not used), at least
        2 vehicles.
    condition_depths : tuple of float
        Depth/height (m) of every anomaly in each further road condition (besides the default
        road, whose anomalies are 2.5-10 cm).
    snr_thresholds : tuple of float
        Grid of ``DetectorSpec.snr_threshold`` (dimensionless, > 0).
    min_depths : tuple of float
        Grid of ``DetectorSpec.min_depth``, m (>= 0).
    detector : DetectorSpec
        The other detector parameters; its ``snr_threshold`` and ``min_depth`` are the reference
        point whose gap to the best point is reported.
    tolerance : float
        Center distance, m, within which a detection matches a true anomaly.
    """

    seeds: tuple[int, ...] = (1000, 1001, 1002, 1003, 1004)
    runs_per_seed: int = 8
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    condition_depths: tuple[float, ...] = (0.02, 0.03)
    snr_thresholds: tuple[float, ...] = (3.5, 4.0, 4.25, 4.5, 5.0, 5.5)
    min_depths: tuple[float, ...] = (0.005, 0.0075, 0.01, 0.0125, 0.015)
    detector: DetectorSpec = field(default_factory=DetectorSpec)
    tolerance: float = 1.0

    def __post_init__(self):
        if not isinstance(self.seeds, (tuple, list)) or len(self.seeds) == 0:
            raise ParameterError(f"seeds must be a non-empty tuple of integers, got {self.seeds!r}")
        seeds = tuple(check_int(f"seeds[{i}]", s, low=0) for i, s in enumerate(self.seeds))
        if len(set(seeds)) != len(seeds):
            raise ParameterError(f"seeds must be distinct, got {seeds}")
        evaluation = sorted(set(seeds) & set(EVALUATION_SEEDS))
        if evaluation:
            raise ParameterError(f"seeds must be training seeds, not evaluation seeds {list(EVALUATION_SEEDS)} "
                                 f"(the default seed of `roadcollab anomalies`), got {evaluation}")
        object.__setattr__(self, "seeds", seeds)
        check_int("runs_per_seed", self.runs_per_seed, low=1)
        if not isinstance(self.experiment, ExperimentConfig):
            raise ParameterError(f"experiment must be an ExperimentConfig, got {type(self.experiment).__name__}")
        depths = _check_levels("condition_depths", self.condition_depths, positive=True)
        if len(set(depths)) != len(depths):
            raise ParameterError(f"condition_depths must not repeat a depth, got {depths}")
        object.__setattr__(self, "condition_depths", depths)
        object.__setattr__(self, "snr_thresholds", _check_grid("snr_thresholds", self.snr_thresholds,
                                                               low_open=True))
        object.__setattr__(self, "min_depths", _check_grid("min_depths", self.min_depths, low_open=False))
        if not isinstance(self.detector, DetectorSpec):
            raise ParameterError(f"detector must be a DetectorSpec, got {type(self.detector).__name__}")
        object.__setattr__(self, "tolerance", check_positive("tolerance", self.tolerance))
        self.study_config()   # validates the fleet size and the condition depths against the road model

    @property
    def conditions(self) -> tuple[str, ...]:
        """Names of the road conditions: ``"default"``, then ``"all_<depth>mm"`` per condition depth."""
        return ("default",) + tuple(f"all_{1000 * d:g}mm" for d in self.condition_depths)

    def study_config(self) -> AnomalyStudyConfig:
        """The anomaly study of one training seed: its default condition and depth sweep are the
        calibration's conditions (no noise sweep)."""
        return AnomalyStudyConfig(experiment=self.experiment, n_runs=self.runs_per_seed,
                                  depths=self.condition_depths, noise_levels=(), detector=self.detector,
                                  tolerance=self.tolerance)

    def grid(self) -> list[DetectorSpec]:
        """Detector of every grid point, ``snr_threshold``-major."""
        return [dataclasses.replace(self.detector, snr_threshold=t, min_depth=d)
                for t in self.snr_thresholds for d in self.min_depths]

    def to_dict(self) -> dict:
        """JSON-ready configuration (nested dataclasses as dicts)."""
        return dataclasses.asdict(self)


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
        """``J(best) - J(point)`` and its paired standard error over the seeds (NaN for 1 seed)."""
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


def parse_seeds(items: Sequence[str] | str) -> tuple[int, ...]:
    """Seeds from command-line text: integers and inclusive ranges ``a-b``, comma or space separated.

    Parameters
    ----------
    items : str or sequence of str
        E.g. ``"1000-1004"`` or ``["1000", "1002,1005-1006"]``.

    Returns
    -------
    tuple of int
        In the given order, ranges expanded.

    Raises
    ------
    ParameterError
        On text that is not a non-negative integer or an ascending range.

    Examples
    --------
    >>> parse_seeds(["1000-1002", "7"])
    (1000, 1001, 1002, 7)
    """
    parts = [t for item in ([items] if isinstance(items, str) else list(items)) for t in item.split(",")]
    out: list[int] = []
    for text in (t.strip() for t in parts):
        lo, sep, hi = text.partition("-")
        if not (lo.isdigit() and (not sep or hi.isdigit())):
            raise ParameterError(f"seeds must be integers >= 0 or ranges 'a-b', got {text!r}")
        if sep and int(hi) < int(lo):
            raise ParameterError(f"seeds range must be ascending, got {text!r}")
        out.extend(range(int(lo), int(hi if sep else lo) + 1))
    if not out:
        raise ParameterError(f"seeds must name at least one seed, got {items!r}")
    return tuple(out)


@dataclass(frozen=True)
class _CalibrationTask:
    """Picklable task: run ``k`` is run ``k % runs_per_seed`` of seed ``seeds[k // runs_per_seed]``;
    returns, per run, ``(grid index, condition index, estimator) -> _Tally`` over vehicles 2..V."""

    config: AnomalyCalibrationConfig

    def __call__(self, indices) -> list[dict]:
        config = self.config
        study = config.study_config()
        grid = [dataclasses.replace(study, detector=spec) for spec in config.grid()]
        pooled = range(1, config.experiment.n_vehicles)   # vehicles 2..V
        out = []
        for k in indices:
            seed = config.seeds[k // config.runs_per_seed]
            pipe, depth_pipes = _condition_pipelines(study, seed)
            rs = _run_seeds(seed, config.runs_per_seed)[k % config.runs_per_seed]
            # Estimates once per condition; only detection and scoring per grid point.
            ests = [run_estimates(p, _fresh(rs)) for p in (pipe, *depth_pipes)]
            rec: dict = {}
            for g, cfg in enumerate(grid):   # grid-major: the detector's template cache stays warm
                for c, est in enumerate(ests):
                    matches = _score(est, cfg, pooled)[1]
                    for name in ESTIMATORS:
                        tally = rec[g, c, name] = _Tally()
                        for j in pooled:
                            tally.add(matches[name, j])
            out.append(rec)
        return out


def _objective(tallies: dict, g: int, n_conditions: int) -> float:
    return float(np.mean([tallies[g, c, e].row()["f1"] for c in range(n_conditions) for e in OBJECTIVE_ESTIMATORS]))


def calibrate_anomalies(config: AnomalyCalibrationConfig, *, progress: Callable[[int], None] | None = None,
                        workers: int | None = None, scheduler: str | None = None) -> AnomalyCalibrationResult:
    """Grid search of the detector's ``snr_threshold`` and ``min_depth`` on training seeds.

    Parameters
    ----------
    config : AnomalyCalibrationConfig
    progress : callable, optional
        Called with the number of finished runs (of ``len(seeds) * runs_per_seed``).
    workers : int, optional
        Local Dask cluster with this many worker processes (identical results).
    scheduler : str, optional
        Address of an existing Dask scheduler.

    Returns
    -------
    AnomalyCalibrationResult

    Raises
    ------
    ParameterError
        If ``config`` is not an :class:`AnomalyCalibrationConfig` (whose construction refuses
        evaluation seeds).

    Examples
    --------
    >>> cfg = AnomalyCalibrationConfig(seeds=(1000,), runs_per_seed=1,
    ...                                experiment=ExperimentConfig(n_vehicles=3),
    ...                                snr_thresholds=(4.0, 4.5), min_depths=(0.01,))
    >>> res = calibrate_anomalies(cfg)                                  # doctest: +SKIP
    >>> res.best.snr_threshold, res.best.min_depth                      # doctest: +SKIP
    """
    from ..experiments.runner import map_runs

    if not isinstance(config, AnomalyCalibrationConfig):
        raise ParameterError(f"config must be an AnomalyCalibrationConfig, got {type(config).__name__}")
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be callable or None, got {type(progress).__name__}")
    t0 = time.perf_counter()
    S, R = len(config.seeds), config.runs_per_seed
    n_grid, n_cond = len(config.snr_thresholds) * len(config.min_depths), len(config.conditions)
    keys = [(g, c, e) for g in range(n_grid) for c in range(n_cond) for e in ESTIMATORS]
    per_seed = [{key: _Tally() for key in keys} for _ in range(S)]
    total = {key: _Tally() for key in keys}
    runs = map_runs(_CalibrationTask(config), S * R, workers=workers, scheduler=scheduler, progress=progress)
    for k, rec in enumerate(runs):
        for key in keys:
            per_seed[k // R][key].merge(rec[key])
            total[key].merge(rec[key])
    points = []
    for g, spec in enumerate(config.grid()):
        scores = {(cond, e): {m: total[g, c, e].row()[m] for m in ("precision", "recall", "f1", "n_true",
                                                                   "n_detected", "n_matched")}
                  for c, cond in enumerate(config.conditions) for e in ESTIMATORS}
        points.append(CalibrationPoint(snr_threshold=spec.snr_threshold, min_depth=spec.min_depth,
                                       objective=_objective(total, g, n_cond),
                                       seed_objectives=tuple(_objective(t, g, n_cond) for t in per_seed),
                                       scores=scores))
    return AnomalyCalibrationResult(config=config, points=tuple(points), elapsed_s=time.perf_counter() - t0)


def _flatness_lines(result: AnomalyCalibrationResult) -> list[str]:
    from ..reporting.records import fmt

    cfg, best, n = result.config, result.best, len(result.points)
    gaps = [result.gap(p) for p in result.points]
    lines = []
    for tol in (0.002, 0.005, 0.01, 0.02):
        near = [p for p, (gap, _) in zip(result.points, gaps) if gap <= tol]
        lines.append(f"- within {tol:g} of the best objective: {len(near)} of {n} points"
                     + (": " + ", ".join(f"({p.snr_threshold:g}, {1000 * p.min_depth:g} mm)" for p in near)
                        if len(near) <= 8 else ""))
    if len(cfg.seeds) > 1:
        tied = [p for p, (gap, se) in zip(result.points, gaps) if gap <= 2 * se or p is best]
        lines.append(f"- within two paired standard errors (over the {len(cfg.seeds)} seeds) of the best: "
                     f"{len(tied)} of {n} points: "
                     + ", ".join(f"({p.snr_threshold:g}, {1000 * p.min_depth:g} mm)" for p in tied))
    obj = [p.objective for p in result.points]
    lines.append(f"- objective range over the grid: {fmt(min(obj))} to {fmt(max(obj))}")
    lines += ["", "Objective (rows `snr_threshold`, columns `min_depth`):", "",
              "| snr_threshold | " + " | ".join(f"{1000 * d:g} mm" for d in cfg.min_depths) + " |",
              "|---|" + "---|" * len(cfg.min_depths)]
    it = iter(result.points)
    for t in cfg.snr_thresholds:
        cells = [next(it) for _ in cfg.min_depths]
        lines.append(f"| {t:g} | " + " | ".join(
            f"**{fmt(p.objective)}**" if p is best else fmt(p.objective) for p in cells) + " |")
    return lines


def calibration_markdown(result: AnomalyCalibrationResult) -> str:
    """The body of the calibration report (best point, flatness, per-point table)."""
    from ..reporting.records import fmt, markdown_table

    cfg, best = result.config, result.best
    exp = cfg.experiment
    contiguous = len(cfg.seeds) > 1 and cfg.seeds == tuple(range(cfg.seeds[0], cfg.seeds[-1] + 1))
    seeds = f"{cfg.seeds[0]}..{cfg.seeds[-1]}" if contiguous else ", ".join(map(str, cfg.seeds))
    lo, hi = exp.road_spec().depth_range
    conds = ", ".join([f"default road (anomalies {100 * lo:g}-{100 * hi:g} cm)"]
                      + [f"every anomaly {100 * d:g} cm" for d in cfg.condition_depths])
    lines = [
        f"Training seeds {seeds} (never the evaluation seeds {list(EVALUATION_SEEDS)}), {cfg.runs_per_seed} runs "
        f"each; {exp.n_vehicles} vehicles, ISO class {exp.iso_class}, {exp.speed:g} m/s, sensor noise "
        f"{exp.sensor_noise_std:g} m/s^2; conditions: {conds}; vehicles 2..{exp.n_vehicles} pooled; a detection "
        f"matches within {cfg.tolerance:g} m. Objective: mean F1 of {' and '.join(OBJECTIVE_ESTIMATORS)} over "
        f"the conditions.",
        "",
        "## Best point",
        "",
        f"Best point: snr_threshold = {best.snr_threshold:g}, min_depth = {best.min_depth:g} m "
        f"(objective {fmt(best.objective)}).",
        "",
    ]
    ref = result.reference
    det = f"The configured detector ({cfg.detector.snr_threshold:g}, {1000 * cfg.detector.min_depth:g} mm)"
    if ref is None:
        lines.append(f"{det} is not on the grid.")
    elif ref is best:
        lines.append(f"{det} is the best point.")
    else:
        gap, se = result.gap(ref)
        lines.append(f"{det}: objective {fmt(ref.objective)}, {fmt(gap)} below the best (paired standard error "
                     f"over seeds {fmt(se)}).")
    lines += ["", "F1 of the best point:", "",
              markdown_table([{"condition": c, **{e: best.scores[c, e]["f1"] for e in ESTIMATORS}}
                              for c in cfg.conditions], ["condition", *ESTIMATORS]),
              "", "## Flatness of the optimum", "", *_flatness_lines(result), "",
              "## Every grid point (`calibration.csv`)", ""]
    cols = ["snr_threshold", "min_depth_m", "objective", "gap_to_best", "gap_se"] + [
        f"f1_{c}_{e}" for c in cfg.conditions for e in OBJECTIVE_ESTIMATORS]
    lines.append(markdown_table(result.to_rows(), cols))
    return "\n".join(lines) + "\n"


def write_calibration(result: AnomalyCalibrationResult, out, *, command: str) -> Path:
    """Write ``calibration.csv``, ``config.json`` and ``report.md`` of a calibration to ``out``.

    Parameters
    ----------
    result : AnomalyCalibrationResult
    out : str or Path
        Output folder (created if missing).
    command : str
        The command line of the run (recorded in config.json and the report).

    Returns
    -------
    Path
        ``out``.
    """
    from ..reporting.records import write_config, write_csv

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "calibration.csv", result.to_rows())
    write_config(out / "config.json", command=command, seed=None, config=result.config.to_dict(),
                 extra={"seeds": list(result.config.seeds), "elapsed_s": result.elapsed_s})
    (out / "report.md").write_text("\n".join([
        "# roadcollab calibrate-anomalies: detector threshold and depth floor on training seeds", "",
        f"Command: `{command}`  ", f"{result.elapsed_s:.1f} s.", "", calibration_markdown(result)]))
    return out
