"""Pooling colluders against the robust fusion node and the corroborated anomaly map (issue 20, section 3).

Per run every vehicle sends its own posterior inversion (as :mod:`.fusion_poisoning`); ``c`` of the
``n`` vehicles collude: they pool their honest ``z`` and all send the *same* message built from the
pooled mean ``z_p``, with full knowledge of the node (its rule, its scale, the honest fused estimate
``mu`` it would return, the true anomalies):

============ ==================================================================================
``fake``     ``z_p`` plus ``n`` times the band-limited signature of a 5 cm pothole where there is
             none (the plain mean would show it at full depth)
``erase``    ``z_p`` minus ``n`` times the signatures of every true anomaly
``weight``   ``1.5 z_p``: a road-correlated exaggeration that looks self-consistent (what bought the
             colluders 4 x an honest vehicle's weight each under ``weighted_huber``)
``edge``     ``mu + huber_c * s * sign(mu)``: every colluder exactly at the node's Huber corner on every
             sample (``s``: the node's common scale from the honest inputs), the largest shift that
             still carries full weight: the bounded-influence worst case
``inside``   ``mu + sqrt(0.95 k D_med) * s * sign(mu)``: a coherent, road-correlated bias on every band
             shaped to sit just inside the vehicle-level screening of ``screened_biweight``
             (``k``: its ``screen_k``, ``D_med``: the median honest vehicle score)
============ ==================================================================================

The colluders also vote: their own detections (of the message they sent) go to the corroboration,
which needs :func:`~roadcollab.detection.corroboration.min_votes_for` ``(n)`` votes. Fleets of
``n < 10`` are the first ``n`` vehicles of the fleet; the colluders are the last ``c`` of them.
"""

from __future__ import annotations

import numpy as np

from ..._validation import check_int
from ...collaboration.robust_fusion import RobustFusion, common_scale, fuse_inversions, vehicle_scores
from ...detection.corroboration import corroborate, min_votes_for
from ...detection.scoring import lost_anomalies, new_false_detections
from ...errors import ParameterError
from ..anomalies.config import AnomalyStudyConfig
from .fusion_poisoning import PoisoningSummary, _fake_site, _honest_run, _row, _score, _TOLERANCE
from ..pipeline import FleetPipeline, fleet_and_run_seeds
from ..seeds import SeedPlan

__all__ = ["COLLUSION_ATTACKS", "collusion_rows"]

COLLUSION_ATTACKS = ("fake", "erase", "weight", "edge", "inside")


def _colluding_z(attack: str, run, z: np.ndarray, c: int, mu: np.ndarray, fusion: RobustFusion) -> np.ndarray:
    """The one message all ``c`` colluders (the last ``c`` rows of ``z``) send."""
    n = z.shape[0]
    pooled = z[n - c:].mean(axis=0)
    if attack == "fake":
        return pooled + n * run.signature(_fake_site(run))
    if attack == "erase":
        return pooled - n * sum((run.signature(a) for a in run.road.anomalies), np.zeros_like(pooled))
    if attack == "weight":
        return 1.5 * pooled
    if attack == "edge":
        corner = fusion.biweight_c / np.sqrt(5.0) if fusion.rule == "common_biweight" else fusion.huber_c
        return mu + corner * common_scale(z)[None, :] * np.sign(mu)
    if attack == "inside":
        amp = np.sqrt(0.95 * fusion.screen_k * np.median(vehicle_scores(z)))
        return mu + amp * common_scale(z)[None, :] * np.sign(mu)
    raise ParameterError(f"attack must be one of {COLLUSION_ATTACKS}, got {attack!r}")


def collusion_rows(config: AnomalyStudyConfig, seed: int, *, n_runs: int = 4, fleet_sizes=(10,),
                   colluders=None, attacks=COLLUSION_ATTACKS, fusion: RobustFusion = RobustFusion(),
                   min_votes: int | None = None, pipe=None) -> list[PoisoningSummary]:
    """Measure pooling colluders against the robust node for every fleet size and coalition size.

    Parameters
    ----------
    config : AnomalyStudyConfig
        Fleet, road (with anomalies) and detector of the anomaly study.
    seed : int
        Root seed (fleet and runs as :func:`~roadcollab.experiments.pipeline.fleet_and_run_seeds`).
    n_runs : int
        Road segments.
    fleet_sizes : sequence of int
        ``n``: the first ``n`` vehicles of the fleet report (at most the fleet size).
    colluders : sequence of int, optional
        Coalition sizes ``c``; default ``1 ... floor((n - 1) / 2)`` per ``n``.
    attacks : sequence of str
        Subset of :data:`COLLUSION_ATTACKS`.
    fusion : RobustFusion
        The node's rule.
    min_votes : int, optional
        Votes a report needs; default :func:`~roadcollab.detection.corroboration.min_votes_for` ``(n)``.
    pipe : FleetPipeline, optional
        The pipeline of ``config.experiment`` and ``seed`` if already built.

    Returns
    -------
    list of PoisoningSummary
        Strategy ``collusion_c{c}_{attack}``, target ``fused_robust`` for the whole fleet and
        ``fused_robust_n{n}`` for a smaller ``n``.
    """
    n_runs = check_int("n_runs", n_runs, low=1)
    exp = config.experiment
    sizes = [check_int("fleet_sizes", n, low=1, high=exp.n_vehicles) for n in fleet_sizes]
    bad = [a for a in attacks if a not in COLLUSION_ATTACKS]
    if bad:
        raise ParameterError(f"attacks must be among {COLLUSION_ATTACKS}, got {bad}")
    pipe = FleetPipeline(exp, fleet_and_run_seeds(exp, seed)[0]) if pipe is None else pipe
    run_seeds = SeedPlan(seed).runs(n_runs)
    road_spec = config.road_spec()
    acc: dict[tuple[str, str], list] = {}
    for r in range(n_runs):
        run = _honest_run(pipe, run_seeds[r], road_spec, None)
        for n in sizes:
            z, own = run.z[:n], run.own[:n]
            votes = min_votes_for(n) if min_votes is None else min_votes
            honest = [run.message(zi) for zi in z]
            mu = fuse_inversions(honest, run.grid, fusion).z
            rep_h = corroborate(run.detect(mu), own, min_votes=votes, tolerance=_TOLERANCE)
            mse_h = _score(run, mu)
            target = "robust" if n == exp.n_vehicles else f"robust_n{n}"        # _row prefixes "fused_"
            for c in (range(1, (n - 1) // 2 + 1) if colluders is None else colluders):
                c = check_int("colluders", c, low=1, high=n - 1)
                for attack in attacks:
                    zc = _colluding_z(attack, run, z, c, mu, fusion)
                    msgs = honest[:n - c] + [run.message(zc)] * c
                    zf = fuse_inversions(msgs, run.grid, fusion).z
                    mine = run.detect(zc)
                    rep = corroborate(run.detect(zf), own[:n - c] + [mine] * c, min_votes=votes,
                                      tolerance=_TOLERANCE)
                    acc.setdefault((f"collusion_c{c}_{attack}", target), []).append((
                        mse_h, _score(run, zf),
                        new_false_detections(rep, rep_h, run.road.anomalies, tolerance=_TOLERANCE),
                        lost_anomalies(rep, rep_h, run.road.anomalies, tolerance=_TOLERANCE), 0))
    return [_row(s, t, v) for (s, t), v in acc.items()]
