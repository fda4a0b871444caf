"""Per-run machinery of the anomaly study, shared with the detector calibration.

The conditions of a study (default road, every anomaly of one depth) share one fleet and its
estimators; only the road changes (:class:`RoadOverride`). Each run's seed is reused for every
condition (its streams are stateless, :mod:`roadcollab.experiments.seeds`), so the conditions see
common random numbers.
:func:`score_estimates` detects anomalies in one run's estimates and scores them on the scored
segment.
"""

from __future__ import annotations

import numpy as np

from ..detection.detector import detect_anomalies
from ..detection.scoring import match_detections
from ..models.road import RoadSpec, generate_road, with_anomalies
from ..io.profiles import measured_road
from .anomaly_config import ESTIMATORS, AnomalyStudyConfig
from .estimates import RunEstimates
from .pipeline import FleetPipeline, pipeline_for
from .seeds import SeedPlan

__all__ = ["RoadOverride", "condition_pipelines", "run_seed_sequences", "score_estimates",
           "scored_region"]


class RoadOverride:
    """A :class:`FleetPipeline` whose roads come from another :class:`RoadSpec`.

    :func:`~roadcollab.experiments.estimates.run_estimates` only uses ``config``, ``grid``,
    ``estimators`` and ``road(rng)``; the estimators (designed for the configuration's road
    statistics) are shared, so a sweep changes the road and nothing else. ``road`` mirrors
    :meth:`FleetPipeline.road`; with a measured profile, the anomalies of ``spec`` are added to it.

    Parameters
    ----------
    pipe : FleetPipeline or RoadOverride
        Whose configuration, grid, fleet and estimators are shared.
    spec : RoadSpec
        Road model of the condition.
    """

    def __init__(self, pipe: FleetPipeline, spec: RoadSpec) -> None:
        self.config, self.grid, self.fleet, self.estimators = pipe.config, pipe.grid, pipe.fleet, pipe.estimators
        self.spec = spec

    def road(self, rng: np.random.Generator):
        """Draw the condition's road and sample it for the fleet's speed.

        Parameters
        ----------
        rng : numpy.random.Generator

        Returns
        -------
        TimeRoad
            Sampled at ``config.speed`` m/s and ``config.sample_rate`` Hz for ``n_samples``.
        """
        cfg = self.config
        if cfg.road_profile is None:
            profile = generate_road(self.spec, rng=rng)
        else:
            path = None if cfg.road_profile == "packaged" else cfg.road_profile
            profile = with_anomalies(measured_road(path, spacing=self.spec.spacing, rng=rng), self.spec, rng=rng)
        return profile.sample(cfg.speed, cfg.sample_rate, duration=cfg.n_samples / cfg.sample_rate)


def scored_region(est: RunEstimates) -> tuple[float, float]:
    """Road stretch of the scored samples.

    Parameters
    ----------
    est : RunEstimates

    Returns
    -------
    (float, float)
        Positions of the first and the last scored sample, m.
    """
    sl = est.scored
    return float(est.positions[sl.start]), float(est.positions[sl.stop - 1])


def score_estimates(est: RunEstimates, config: AnomalyStudyConfig, vehicles) -> tuple[dict, dict]:
    """Detections and their scores of every estimator for some vehicles of one run.

    Parameters
    ----------
    est : RunEstimates
    config : AnomalyStudyConfig
        Detector, match tolerance (m), speed and sample rate.
    vehicles : iterable of int
        0-based vehicle indices.

    Returns
    -------
    detections : dict
        ``(estimator, vehicle) -> list of Detection``.
    matches : dict
        ``(estimator, vehicle) -> MatchResult`` on :func:`scored_region`.
    """
    exp = config.experiment
    region = scored_region(est)
    dets, matches = {}, {}
    for name in ESTIMATORS:
        w = getattr(est, name)
        for j in vehicles:
            dets[name, j] = detect_anomalies(w[j], positions=est.positions, speed=exp.speed,
                                             sample_rate=exp.sample_rate, spec=config.detector)
            matches[name, j] = match_detections(dets[name, j], est.road.anomalies, tolerance=config.tolerance,
                                                region=region)
    return dets, matches


def run_seed_sequences(seed: int, n_runs: int) -> list[np.random.SeedSequence]:
    """One SeedSequence per run (:meth:`roadcollab.experiments.seeds.SeedPlan.runs`; the plan's
    fleet stream draws the fleet).

    Parameters
    ----------
    seed : int
        Root seed.
    n_runs : int

    Returns
    -------
    list of numpy.random.SeedSequence
        ``n_runs`` children.
    """
    return SeedPlan(seed).runs(n_runs)


def condition_pipelines(config: AnomalyStudyConfig, seed: int) -> tuple[RoadOverride, list[RoadOverride]]:
    """The default condition's pipeline and one per sweep depth (same fleet and estimators).

    Parameters
    ----------
    config : AnomalyStudyConfig
    seed : int
        Root seed of the fleet (:func:`~roadcollab.experiments.pipeline.pipeline_for`).

    Returns
    -------
    default : RoadOverride
        The configured road.
    by_depth : list of RoadOverride
        One per ``config.depths``, every anomaly that deep (high).
    """
    pipe = RoadOverride(pipeline_for(config.experiment, seed), config.road_spec())
    return pipe, [RoadOverride(pipe, config.road_spec(d)) for d in config.depths]
