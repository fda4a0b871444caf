"""Road anomaly detection study: detection quality of each estimator, and its sweeps.

For every run the fleet drives one road; every vehicle's three band-limited estimates
(``observer_only``, ``collaborative`` = Algorithm 1, ``fused`` = running fleet average of the
inversions ``z``; see :func:`roadcollab.experiments.anomalies.estimates.run_estimates`) go through
:func:`roadcollab.detection.detector.detect_anomalies` and are scored with
:func:`roadcollab.detection.scoring.match_detections` on the scored segment (the window minus the lead-in
and lead-out margins), with a center tolerance of ``AnomalyStudyConfig.tolerance``.

Pooling: counts (matches, detections, true anomalies) are summed over runs and over vehicles
2..V, and precision, recall and F1 are computed from the sums; position errors, depth errors,
kind and side agreement are pooled over all matched pairs. Vehicle 1 is left out of the pooled
rows because it has no predecessor: its "collaborative" estimate is its own observer
(``vehicle_rows`` lists every vehicle, vehicle 1 included).

Reproducibility: ``SeedPlan(seed)`` (:mod:`roadcollab.experiments.seeds`) gives the fleet (drawn
once per study) and the runs; run ``i`` uses its seed for *every* condition (default, each depth and
each noise level), so the sweeps use common random numbers (same roughness, anomaly positions
and noise draws; only the swept quantity changes) and results do not depend on scheduling.
The sweep point equal to the configured sensor noise is the default condition itself.

The configuration is :class:`~roadcollab.experiments.anomalies.config.AnomalyStudyConfig`; the
conditions, seeds and per-run scoring are in :mod:`roadcollab.experiments.anomalies.runs`.

Cost: one run is ``1 + len(depths) + len(noise_levels) - 1`` calls of ``run_estimates`` (about
0.05 s each for 10 vehicles) and ``3 V`` detections per condition (about 3 ms each); the default
study (20 runs, 10 vehicles, 6 depths, 5 noise levels) took 16 s with ``--workers 2`` on the
2-core machine, including the pipeline set-up.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence, TypedDict

import numpy as np

from ..._validation import check_int
from ...detection.scoring import MatchResult, MatchTally
from ...errors import ParameterError
from ...models.vehicle import Vehicle, sample_fleet
from .config import ESTIMATORS, AnomalyStudyConfig
from .rows import (AnomalyMap, DepthDetectionRow, DetectionRow, NoiseDetectionRow,
                   VehicleDetectionRow)
from .runs import condition_roads, run_seed_sequences, score_estimates, scored_region
from .estimates import RunEstimates, run_estimates
from ..pipeline import PipelineCache
from ..runner import map_runs
from ..seeds import SeedPlan

#: Matches of one condition: ``(estimator, vehicle) -> MatchResult`` (vehicle 0-based).
_Matches = dict[tuple[str, int], MatchResult]


class _RunRecord(TypedDict):
    """What one run hands back: the default condition's matches, those per noise level and per
    depth (by sweep index), and run 0's map example."""

    main: _Matches
    noise: dict[int, _Matches]
    depth: dict[int, _Matches]
    map: AnomalyMap | None

__all__ = ["AnomalyStudyResult", "run_anomaly_study"]


@dataclass(frozen=True, eq=False)
class AnomalyStudyResult:
    """Rows of the study (typed, one list per CSV) and the map example.

    Attributes
    ----------
    config : AnomalyStudyConfig
    seed : int
        Root seed.
    fleet : list of Vehicle
        The fleet of every run and condition.
    detection_rows : list of DetectionRow
        One per estimator on the default condition, pooled over runs and vehicles 2..V.
    depth_rows : list of DepthDetectionRow
        Per sweep depth and estimator.
    noise_rows : list of NoiseDetectionRow
        Per noise level and estimator.
    vehicle_rows : list of VehicleDetectionRow
        Per vehicle (1-based) and estimator, default condition.
    map_example : AnomalyMap
        Run 1, vehicle ``map_vehicle``.
    elapsed_s : float
        Wall-clock time of the study.
    """

    config: AnomalyStudyConfig
    seed: int
    fleet: list[Vehicle]
    detection_rows: list[DetectionRow]
    depth_rows: list[DepthDetectionRow]
    noise_rows: list[NoiseDetectionRow]
    vehicle_rows: list[VehicleDetectionRow]
    map_example: AnomalyMap
    elapsed_s: float


@dataclass(frozen=True)
class _AnomalyTask:
    """Picklable task: the matches (:class:`~roadcollab.detection.scoring.MatchResult`) of runs
    ``indices`` under every condition."""

    config: AnomalyStudyConfig
    seed: int

    def __call__(self, indices: Sequence[int], cache: PipelineCache) -> list[_RunRecord]:
        config, exp = self.config, self.config.experiment
        pipe, default, by_depth = condition_roads(config, self.seed, cache)
        runs_ss = run_seed_sequences(self.seed, config.n_runs)
        V = exp.n_vehicles
        pooled = range(1, V)   # vehicles 2..V
        out: list[_RunRecord] = []
        for i in indices:
            rs = runs_ss[i]
            est = run_estimates(pipe, rs, road_spec=default)
            dets, matches = score_estimates(est, config, range(V))
            rec: _RunRecord = {"main": matches, "noise": {}, "depth": {},
                   "map": _map_example(est, dets, config) if i == 0 else None}
            for k, level in enumerate(config.noise_levels):
                nm = matches   # the default condition itself (same seeds) ...
                if level != exp.sensor_noise_std:   # ... unless the level differs
                    noisy = run_estimates(pipe, rs, sensor_noise_std=level, road_spec=default)
                    nm = score_estimates(noisy, config, pooled)[1]
                rec["noise"][k] = nm
            for k, spec in enumerate(by_depth):
                rec["depth"][k] = score_estimates(run_estimates(pipe, rs, road_spec=spec), config, pooled)[1]
            out.append(rec)
        return out


def run_anomaly_study(config: AnomalyStudyConfig, seed: int, *, progress: Callable[[int], None] | None = None,
                      workers: int | None = None, scheduler: str | None = None) -> AnomalyStudyResult:
    """Run the anomaly-detection study, serially or on Dask (identical results).

    Parameters
    ----------
    config : AnomalyStudyConfig
    seed : int
        Root seed (>= 0); fleet and runs get independent SeedSequence children.
    progress : callable, optional
        Called with the number of finished runs.
    workers : int, optional
        Local process pool with this many worker processes (identical results).
    scheduler : str, optional
        Address of an existing Dask scheduler.

    Returns
    -------
    AnomalyStudyResult
    """
    if not isinstance(config, AnomalyStudyConfig):
        raise ParameterError(f"config must be an AnomalyStudyConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be callable or None, got {type(progress).__name__}")
    t0 = time.perf_counter()
    exp = config.experiment
    fleet = sample_fleet(exp.n_vehicles, exp.fleet, rng=np.random.default_rng(SeedPlan(seed).fleet()))
    V = exp.n_vehicles
    main = {name: MatchTally() for name in ESTIMATORS}
    per_vehicle = {(name, j): MatchTally() for name in ESTIMATORS for j in range(V)}
    by_depth = {(i, name): MatchTally() for i in range(len(config.depths)) for name in ESTIMATORS}
    by_noise = {(i, name): MatchTally() for i in range(len(config.noise_levels)) for name in ESTIMATORS}
    pooled = range(1, V)   # vehicles 2..V
    cache = PipelineCache()
    if scheduler is None:   # the fleet's setup built here once, inherited by a forked pool
        condition_roads(config, seed, cache)
    runs = map_runs(_AnomalyTask(config, seed), config.n_runs, workers=workers, scheduler=scheduler,
                    progress=progress, shared=cache)
    for rec in runs:
        for (name, j), m in rec["main"].items():
            per_vehicle[name, j].add(m)
            if j in pooled:
                main[name].add(m)
        for k, nm in rec["noise"].items():
            for name in ESTIMATORS:
                for j in pooled:
                    by_noise[k, name].add(nm[name, j])
        for k, dm in rec["depth"].items():
            for (name, _j), m in dm.items():
                by_depth[k, name].add(m)
    map_example = runs[0]["map"]
    assert map_example is not None   # run 0 always carries it

    detection_rows = [DetectionRow.of(main[name].scores(), estimator=name) for name in ESTIMATORS]
    vehicle_rows = [VehicleDetectionRow.of(per_vehicle[(name, j)].scores(), vehicle=j + 1, estimator=name)
                    for j in range(V) for name in ESTIMATORS]
    depth_rows = [DepthDetectionRow.of(by_depth[(k, name)].scores(), depth_m=d, estimator=name)
                  for k, d in enumerate(config.depths) for name in ESTIMATORS]
    noise_rows = [NoiseDetectionRow.of(by_noise[(k, name)].scores(), sensor_noise_std=s, estimator=name)
                  for k, s in enumerate(config.noise_levels) for name in ESTIMATORS]
    return AnomalyStudyResult(config=config, seed=seed, fleet=fleet, detection_rows=detection_rows,
                              depth_rows=depth_rows, noise_rows=noise_rows, vehicle_rows=vehicle_rows,
                              map_example=map_example, elapsed_s=time.perf_counter() - t0)


def _map_example(est: RunEstimates, dets: dict, config: AnomalyStudyConfig) -> AnomalyMap:
    """Truth and detections of vehicle ``map_vehicle`` on one run (see ``AnomalyStudyResult.map_example``)."""
    j = config.map_vehicle - 1
    return AnomalyMap(vehicle=config.map_vehicle, run=1, region=scored_region(est), tolerance=config.tolerance,
                      truth=tuple(est.road.anomalies),
                      detections={name: tuple(dets[name, j]) for name in ESTIMATORS})
