"""Per-run machinery of the anomaly study, shared with the detector calibration.

The conditions of a study (default road, every anomaly of one depth) share one fleet and its
estimators; only the road changes (a :class:`~roadcollab.models.road.RoadSpec` per condition,
passed to :func:`~roadcollab.experiments.anomalies.estimates.run_estimates`). Each run's seed is reused for every
condition (its streams are stateless, :mod:`roadcollab.experiments.seeds`), so the conditions see
common random numbers.
:func:`score_estimates` detects anomalies in one run's estimates and scores them on the scored
segment.
"""

from __future__ import annotations

import numpy as np

from ...detection.detector import detect_anomalies
from ...detection.scoring import match_detections
from ...models.road import RoadSpec
from .config import ESTIMATORS, AnomalyStudyConfig
from .estimates import RunEstimates
from ..pipeline import FleetPipeline, PipelineCache
from ..seeds import SeedPlan

__all__ = ["condition_roads", "run_seed_sequences", "score_estimates",
           "scored_region"]


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


def condition_roads(config: AnomalyStudyConfig, seed: int, cache: PipelineCache
                    ) -> tuple[FleetPipeline, RoadSpec, list[RoadSpec]]:
    """The fleet pipeline and the road conditions of a study (same fleet and estimators for all).

    Parameters
    ----------
    config : AnomalyStudyConfig
    seed : int
        Root seed of the fleet (:meth:`~roadcollab.experiments.pipeline.PipelineCache.pipeline`).
    cache : PipelineCache
        The study's cache, which builds the pipeline once.

    Returns
    -------
    pipe : FleetPipeline
    default : RoadSpec
        The configured road.
    by_depth : list of RoadSpec
        One per ``config.depths``, every anomaly that deep (high).
    """
    return cache.pipeline(config.experiment, seed), config.road_spec(), [config.road_spec(d) for d in config.depths]
