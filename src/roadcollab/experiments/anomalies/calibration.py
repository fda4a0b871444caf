"""Calibration of the anomaly detector's threshold and depth floor on *training* seeds.

The detector's ``snr_threshold`` and ``min_depth`` (:class:`roadcollab.detection.detector.DetectorSpec`)
are chosen by a grid search on training runs that the evaluation (``roadcollab anomalies``,
seed 0) never sees; this module ships that procedure as ``roadcollab calibrate-anomalies``.

Procedure
---------
For every training root seed ``s`` (default 1000..1004), ``SeedPlan(s)`` gives the fleet and the
runs, exactly as in
:func:`roadcollab.experiments.anomalies.study.run_anomaly_study` (the same helpers,
:mod:`roadcollab.experiments.anomalies.runs`, build the pipelines and the per-run seeds, so
training seed ``s`` with ``runs_per_seed`` runs is the study with root seed ``s`` and
``n_runs = runs_per_seed``). Run ``i`` of seed ``s`` is driven under
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

The configuration and the seed parser are in :mod:`roadcollab.experiments.anomalies.calibration_config`,
the result in :mod:`roadcollab.experiments.anomalies.calibration_result`, and the report writer in
:mod:`roadcollab.reporting.calibration_report`; this module runs the grid search.

Cost: ``len(seeds) * runs_per_seed`` runs, each ``1 + len(condition_depths)`` calls of
``run_estimates`` (about 0.05 s for 10 vehicles) and ``n_grid * n_conditions * 3 * (V - 1)``
detections (about 2 ms each): 5-9 s per run for the default 30-point grid and 10 vehicles; the
default calibration (40 runs) took about 3 min on 2 workers of the 2-core machine.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ...detection.scoring import MatchTally
from ...errors import ParameterError
from .config import ESTIMATORS
from .runs import condition_roads, run_seed_sequences, score_estimates
from .calibration_config import OBJECTIVE_ESTIMATORS, AnomalyCalibrationConfig
from .calibration_result import AnomalyCalibrationResult, CalibrationPoint
from .estimates import run_estimates
from ..pipeline import PipelineCache
from ..runner import map_runs

__all__ = ["calibrate_anomalies"]

#: One run's tallies: ``(grid index, condition index, estimator) -> MatchTally``.
_Tallies = dict[tuple[int, int, str], MatchTally]


@dataclass(frozen=True)
class _CalibrationTask:
    """Picklable task: run ``k`` is run ``k % runs_per_seed`` of seed ``seeds[k // runs_per_seed]``;
    returns, per run, ``(grid index, condition index, estimator) -> MatchTally`` over vehicles 2..V."""

    config: AnomalyCalibrationConfig

    def __call__(self, indices: Sequence[int], cache: PipelineCache) -> list[_Tallies]:
        config = self.config
        study = config.study_config()
        grid = [dataclasses.replace(study, detector=spec) for spec in config.grid()]
        pooled = range(1, config.experiment.n_vehicles)   # vehicles 2..V
        out = []
        for k in indices:
            seed = config.seeds[k // config.runs_per_seed]
            pipe, default, by_depth = condition_roads(study, seed, cache)
            rs = run_seed_sequences(seed, config.runs_per_seed)[k % config.runs_per_seed]
            # Estimates once per condition; only detection and scoring per grid point.
            ests = [run_estimates(pipe, rs, road_spec=spec) for spec in (default, *by_depth)]
            rec: _Tallies = {}
            for g, cfg in enumerate(grid):   # grid-major: the detector's template cache stays warm
                for c, est in enumerate(ests):
                    matches = score_estimates(est, cfg, pooled)[1]
                    for name in ESTIMATORS:
                        tally = rec[g, c, name] = MatchTally()
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
        Local process pool with this many worker processes (identical results).
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
    >>> from roadcollab.experiments.anomalies.calibration_config import AnomalyCalibrationConfig
    >>> from roadcollab.experiments.config import ExperimentConfig
    >>> cfg = AnomalyCalibrationConfig(seeds=(1000,), runs_per_seed=1,
    ...                                experiment=ExperimentConfig(n_vehicles=3),
    ...                                snr_thresholds=(4.0, 4.5), min_depths=(0.01,))
    >>> res = calibrate_anomalies(cfg)                                  # doctest: +SKIP
    >>> res.best.snr_threshold, res.best.min_depth                      # doctest: +SKIP
    """
    if not isinstance(config, AnomalyCalibrationConfig):
        raise ParameterError(f"config must be an AnomalyCalibrationConfig, got {type(config).__name__}")
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be callable or None, got {type(progress).__name__}")
    t0 = time.perf_counter()
    S, R = len(config.seeds), config.runs_per_seed
    n_grid, n_cond = len(config.snr_thresholds) * len(config.min_depths), len(config.conditions)
    keys = [(g, c, e) for g in range(n_grid) for c in range(n_cond) for e in ESTIMATORS]
    per_seed = [{key: MatchTally() for key in keys} for _ in range(S)]
    total = {key: MatchTally() for key in keys}
    cache = PipelineCache()
    if scheduler is None:   # every seed's fleet built here once, inherited by a forked pool
        for seed in config.seeds:
            condition_roads(config.study_config(), seed, cache)
    runs = map_runs(_CalibrationTask(config), S * R, workers=workers, scheduler=scheduler, progress=progress,
                    shared=cache)
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
