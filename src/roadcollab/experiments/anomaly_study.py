"""Road anomaly detection study: detection quality of each estimator, and its sweeps.

For every run the fleet drives one road; every vehicle's three band-limited estimates
(``observer_only``, ``collaborative`` = Algorithm 1, ``fused`` = running fleet average of the
inversions ``z``; see :func:`roadcollab.experiments.reproduction.run_estimates`) go through
:func:`roadcollab.detection.detector.detect_anomalies` and are scored with
:func:`roadcollab.detection.scoring.match_detections` on the scored segment (the window minus the lead-in
and lead-out margins), with a center tolerance of ``AnomalyStudyConfig.tolerance``.

Pooling: counts (matches, detections, true anomalies) are summed over runs and over vehicles
2..V, and precision, recall and F1 are computed from the sums; position errors, depth errors,
kind and side agreement are pooled over all matched pairs. Vehicle 1 is left out of the pooled
rows because it has no predecessor: its "collaborative" estimate is its own observer
(``vehicle_rows`` lists every vehicle, vehicle 1 included).

Reproducibility: ``SeedSequence(seed).spawn(2)`` gives the fleet (drawn once per study) and the
runs' parent; run ``i`` uses the ``i``-th child for *every* condition (default, each depth and
each noise level), so the sweeps use common random numbers (same roughness, anomaly positions
and noise draws; only the swept quantity changes) and results do not depend on scheduling.
The sweep point equal to the configured sensor noise is the default condition itself.

Cost: one run is ``1 + len(depths) + len(noise_levels) - 1`` calls of ``run_estimates`` (about
0.05 s each for 10 vehicles) and ``3 V`` detections per condition (about 3 ms each); the default
study (20 runs, 10 vehicles, 6 depths, 5 noise levels) took 16 s with ``--workers 2`` on the
2-core machine, including the pipeline set-up.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._validation import check_int, check_positive, check_real
from ..detection.detector import DetectorSpec, detect_anomalies
from ..detection.scoring import MatchTally, match_detections
from ..errors import ParameterError
from ..experiments.config import ExperimentConfig
from ..experiments.estimates import RunEstimates, run_estimates
from ..experiments.pipeline import FleetPipeline
from ..models.road import RoadSpec, generate_road, measured_road, with_anomalies
from ..models.vehicle import Vehicle, sample_fleet

__all__ = ["ESTIMATORS", "AnomalyStudyConfig", "AnomalyStudyResult", "run_anomaly_study"]

#: Estimates scored by the study (attributes of :class:`~roadcollab.experiments.reproduction.RunEstimates`).
ESTIMATORS = ("observer_only", "collaborative", "fused")


def _check_levels(name: str, value, *, positive: bool) -> tuple[float, ...]:
    if not isinstance(value, (tuple, list)):
        raise ParameterError(f"{name} must be a tuple of numbers, got {type(value).__name__}")
    check = check_positive if positive else (lambda n, v: check_real(n, v, low=0.0))
    return tuple(check(f"{name}[{i}]", v) for i, v in enumerate(value))


@dataclass(frozen=True)
class AnomalyStudyConfig:
    """Everything the anomaly study depends on besides the seed.

    Parameters
    ----------
    experiment : ExperimentConfig
        Fleet, road and sensors of the default condition (its ``n_runs`` is not used), at
        least 2 vehicles. With ``road_profile`` set, the measured profile's roughness gets
        synthetic anomalies with ground truth (:func:`roadcollab.models.road.with_anomalies`).
    n_runs : int
        Roads (runs); every condition uses the same runs.
    depths : tuple of float
        Anomaly depths/heights (m) of the F1-vs-depth sweep: every anomaly of the default road
        gets this depth (``RoadSpec.depth_range = (d, d)``). Empty: no sweep.
    noise_levels : tuple of float
        Accelerometer noise std (m/s^2) of the F1-vs-noise sweep; the estimators stay designed
        for ``experiment.sensor_noise_std``. Empty: no sweep.
    detector : DetectorSpec
    tolerance : float
        Center distance (m) within which a detection matches a true anomaly.
    map_vehicle : int
        1-based vehicle whose detections on run 1 make ``map_example``.
    """

    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    n_runs: int = 20
    depths: tuple[float, ...] = (0.01, 0.015, 0.02, 0.03, 0.05, 0.08)
    noise_levels: tuple[float, ...] = (0.01, 0.025, 0.05, 0.1, 0.2)
    detector: DetectorSpec = field(default_factory=DetectorSpec)
    tolerance: float = 1.0
    map_vehicle: int = 2

    def __post_init__(self):
        if not isinstance(self.experiment, ExperimentConfig):
            raise ParameterError(f"experiment must be an ExperimentConfig, got {type(self.experiment).__name__}")
        check_int("experiment.n_vehicles", self.experiment.n_vehicles, low=2)
        check_int("n_runs", self.n_runs, low=1)
        object.__setattr__(self, "depths", _check_levels("depths", self.depths, positive=True))
        object.__setattr__(self, "noise_levels", _check_levels("noise_levels", self.noise_levels, positive=False))
        if not isinstance(self.detector, DetectorSpec):
            raise ParameterError(f"detector must be a DetectorSpec, got {type(self.detector).__name__}")
        object.__setattr__(self, "tolerance", check_positive("tolerance", self.tolerance))
        check_int("map_vehicle", self.map_vehicle, low=1, high=self.experiment.n_vehicles)
        for d in self.depths:   # the road spec must accept every sweep depth
            self.road_spec(d)

    def road_spec(self, depth: float | None = None) -> RoadSpec:
        """The default road, or with every anomaly ``depth`` m deep (high)."""
        spec = self.experiment.road_spec()
        return spec if depth is None else dataclasses.replace(spec, depth_range=(depth, depth))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True, eq=False)
class AnomalyStudyResult:
    """Rows of the study (lists of dicts, ready for CSV) and the map example.

    Attributes
    ----------
    detection_rows : list of dict
        One per estimator on the default condition, pooled over runs and vehicles 2..V:
        ``estimator, precision, recall, f1, median_position_error_m, median_depth_rel_error,
        kind_accuracy, side_accuracy, n_true, n_detected, n_matched``.
    depth_rows : list of dict
        The same columns plus ``depth_m``, per sweep depth and estimator.
    noise_rows : list of dict
        The same columns plus ``sensor_noise_std``, per noise level and estimator.
    vehicle_rows : list of dict
        The same columns plus ``vehicle`` (1-based), default condition, per vehicle and estimator.
    map_example : dict
        Run 1, vehicle ``map_vehicle``: ``vehicle``, ``region`` (m), ``truth`` (list of dicts
        ``start, end, center, side, kind, depth``), ``detections`` (estimator -> list of dicts
        ``position, side, kind, depth, confidence``), ``tolerance``.
    elapsed_s : float
        Wall-clock time of the study.
    """

    config: AnomalyStudyConfig
    seed: int
    fleet: list[Vehicle]
    detection_rows: list[dict]
    depth_rows: list[dict]
    noise_rows: list[dict]
    vehicle_rows: list[dict]
    map_example: dict
    elapsed_s: float


class _RoadOverride:
    """A :class:`FleetPipeline` whose roads come from another :class:`RoadSpec`.

    :func:`run_estimates` only uses ``config``, ``grid``, ``estimators`` and ``road(rng)``;
    the estimators (designed for the configuration's road statistics) are shared, so a sweep
    changes the road and nothing else. ``road`` mirrors :meth:`FleetPipeline.road`; with a
    measured profile, the anomalies of ``spec`` are added to it.
    """

    def __init__(self, pipe: FleetPipeline, spec: RoadSpec) -> None:
        self.config, self.grid, self.fleet, self.estimators = pipe.config, pipe.grid, pipe.fleet, pipe.estimators
        self.spec = spec

    def road(self, rng: np.random.Generator):
        cfg = self.config
        if cfg.road_profile is None:
            profile = generate_road(self.spec, rng=rng)
        else:
            path = None if cfg.road_profile == "packaged" else cfg.road_profile
            profile = with_anomalies(measured_road(path, spacing=self.spec.spacing, rng=rng), self.spec, rng=rng)
        return profile.sample(cfg.speed, cfg.sample_rate, duration=cfg.n_samples / cfg.sample_rate)


def _region(est: RunEstimates) -> tuple[float, float]:
    """Road stretch (m) of the scored samples."""
    sl = est.scored
    return float(est.positions[sl.start]), float(est.positions[sl.stop - 1])


def _score(est: RunEstimates, config: AnomalyStudyConfig, vehicles) -> tuple[dict, dict]:
    """Detections and matches of every estimator for the given 0-based ``vehicles`` of one run:
    two dicts ``(estimator, vehicle) -> list of Detection`` and ``-> MatchResult``."""
    exp = config.experiment
    region = _region(est)
    dets, matches = {}, {}
    for name in ESTIMATORS:
        w = getattr(est, name)
        for j in vehicles:
            dets[name, j] = detect_anomalies(w[j], positions=est.positions, speed=exp.speed,
                                             sample_rate=exp.sample_rate, spec=config.detector)
            matches[name, j] = match_detections(dets[name, j], est.road.anomalies, tolerance=config.tolerance,
                                                region=region)
    return dets, matches


def _fresh(ss: np.random.SeedSequence) -> np.random.SeedSequence:
    """An unspawned copy: run_estimates spawns children, and each condition needs the same ones."""
    return np.random.SeedSequence(ss.entropy, spawn_key=ss.spawn_key, pool_size=ss.pool_size)


def _run_seeds(seed: int, n_runs: int) -> list[np.random.SeedSequence]:
    """One SeedSequence per run: the children of ``SeedSequence(seed).spawn(2)[1]`` (the first
    child draws the fleet, see :func:`roadcollab.experiments.reproduction.pipeline_for`)."""
    return np.random.SeedSequence(seed).spawn(2)[1].spawn(n_runs)


def _condition_pipelines(config: AnomalyStudyConfig, seed: int) -> tuple[_RoadOverride, list[_RoadOverride]]:
    """The default condition's pipeline and one per sweep depth (same fleet and estimators)."""
    from ..experiments.pipeline import pipeline_for

    pipe = _RoadOverride(pipeline_for(config.experiment, seed), config.road_spec())
    return pipe, [_RoadOverride(pipe, config.road_spec(d)) for d in config.depths]


@dataclass(frozen=True)
class _AnomalyTask:
    """Picklable task: the matches of runs ``indices`` under every condition."""

    config: AnomalyStudyConfig
    seed: int

    def __call__(self, indices) -> list[dict]:
        config, exp = self.config, self.config.experiment
        pipe, depth_pipes = _condition_pipelines(config, self.seed)
        runs_ss = _run_seeds(self.seed, config.n_runs)
        V = exp.n_vehicles
        pooled = range(1, V)   # vehicles 2..V
        out = []
        for i in indices:
            rs = runs_ss[i]
            est = run_estimates(pipe, _fresh(rs))
            dets, matches = _score(est, config, range(V))
            rec = {"main": matches, "noise": {}, "depth": {},
                   "map": _map_example(est, dets, config) if i == 0 else None}
            for k, level in enumerate(config.noise_levels):
                nm = matches   # the default condition itself (same seeds) ...
                if level != exp.sensor_noise_std:   # ... unless the level differs
                    _, nm = _score(run_estimates(pipe, _fresh(rs), sensor_noise_std=level), config, pooled)
                rec["noise"][k] = nm
            for k, dpipe in enumerate(depth_pipes):
                rec["depth"][k] = _score(run_estimates(dpipe, _fresh(rs)), config, pooled)[1]
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
        Local Dask cluster with this many worker processes.
    scheduler : str, optional
        Address of an existing Dask scheduler.

    Returns
    -------
    AnomalyStudyResult
    """
    from ..experiments.runner import map_runs

    if not isinstance(config, AnomalyStudyConfig):
        raise ParameterError(f"config must be an AnomalyStudyConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be callable or None, got {type(progress).__name__}")
    t0 = time.perf_counter()
    exp = config.experiment
    fleet_ss, _ = np.random.SeedSequence(seed).spawn(2)
    fleet = sample_fleet(exp.n_vehicles, exp.fleet, rng=np.random.default_rng(fleet_ss))
    V = exp.n_vehicles
    main = {name: MatchTally() for name in ESTIMATORS}
    per_vehicle = {(name, j): MatchTally() for name in ESTIMATORS for j in range(V)}
    by_depth = {(i, name): MatchTally() for i in range(len(config.depths)) for name in ESTIMATORS}
    by_noise = {(i, name): MatchTally() for i in range(len(config.noise_levels)) for name in ESTIMATORS}
    pooled = range(1, V)   # vehicles 2..V
    runs = map_runs(_AnomalyTask(config, seed), config.n_runs, workers=workers, scheduler=scheduler,
                    progress=progress)
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
            for (name, j), m in dm.items():
                by_depth[k, name].add(m)
    map_example = runs[0]["map"]

    detection_rows = [{"estimator": name, **main[name].row()} for name in ESTIMATORS]
    vehicle_rows = [{"vehicle": j + 1, "estimator": name, **per_vehicle[(name, j)].row()}
                    for j in range(V) for name in ESTIMATORS]
    depth_rows = [{"depth_m": d, "estimator": name, **by_depth[(k, name)].row()}
                  for k, d in enumerate(config.depths) for name in ESTIMATORS]
    noise_rows = [{"sensor_noise_std": s, "estimator": name, **by_noise[(k, name)].row()}
                  for k, s in enumerate(config.noise_levels) for name in ESTIMATORS]
    return AnomalyStudyResult(config=config, seed=seed, fleet=fleet, detection_rows=detection_rows,
                              depth_rows=depth_rows, noise_rows=noise_rows, vehicle_rows=vehicle_rows,
                              map_example=map_example, elapsed_s=time.perf_counter() - t0)


def _map_example(est: RunEstimates, dets: dict, config: AnomalyStudyConfig) -> dict:
    j = config.map_vehicle - 1
    truth = [{"start": a.position, "end": a.end, "center": a.center, "side": a.side, "kind": a.kind,
              "depth": a.depth} for a in est.road.anomalies]
    return {
        "vehicle": config.map_vehicle, "run": 1, "region": _region(est), "tolerance": config.tolerance,
        "truth": truth,
        "detections": {name: [dataclasses.asdict(d) for d in dets[name, j]] for name in ESTIMATORS},
    }
