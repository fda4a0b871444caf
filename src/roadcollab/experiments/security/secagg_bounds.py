"""How far bounded influence alone could take secure aggregation against one malicious vehicle (issue 20, Sec. 2).

An ideal input-validity check (what a two-server Prio-style proof would enforce) admits any input whose
l2 norm is within a public bound ``B``; to admit every honest input, ``B`` is at least the largest honest
norm. The attacker sends the input at the bound that points against its own honest ``z`` (``-B z / |z|``),
which moves the average by up to ``2 B / n``. This module measures the fused estimate's MSE under that
attacker, with vehicle 1's guard as in ``fused_secagg_guarded`` of :mod:`.fusion_poisoning`, for bounds
``margin x`` the largest honest norm of the run (a bound from road statistics alone can only be looser).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import check_int
from ...collaboration.guard import ReceiverGuard
from ..anomalies.config import AnomalyStudyConfig
from .fusion_poisoning import _honest_run, _score, _secagg_node
from ..pipeline import FleetPipeline, fleet_and_run_seeds
from ..seeds import SeedPlan

__all__ = ["BoundedInfluenceRow", "bounded_influence_ceiling"]


@dataclass(frozen=True)
class BoundedInfluenceRow:
    """One run and bound: the guarded fused MSE under the attacker at the bound, over the honest one.

    Attributes
    ----------
    run : int
    margin : float
        ``B`` over the largest honest l2 norm of the run.
    ratio : float
        Attacked over honest MSE of vehicle 1's guarded estimate.
    refused_bands : int
        Bands vehicle 1's guard refused in the attacked aggregate.
    """

    run: int
    margin: float
    ratio: float
    refused_bands: int


def bounded_influence_ceiling(config: AnomalyStudyConfig, seed: int, *, n_runs: int = 2, malicious: int = 4,
                              margins=(1.0, 1.5)) -> list[BoundedInfluenceRow]:
    """The attacker at an ideal l2 bound against the guarded secure aggregate.

    Parameters
    ----------
    config : AnomalyStudyConfig
        As :func:`~.fusion_poisoning.fusion_poisoning_rows`.
    seed : int
    n_runs : int
    malicious : int
        0-based index of the malicious vehicle.
    margins : sequence of float
        Bounds as multiples of the run's largest honest norm.

    Returns
    -------
    list of BoundedInfluenceRow
    """
    n_runs = check_int("n_runs", n_runs, low=1)
    exp = config.experiment
    pipe = FleetPipeline(exp, fleet_and_run_seeds(exp, seed)[0])
    guard = ReceiverGuard(pipe.estimators[0], pipe.road_moment, exp.sensor_noise_std)
    rows = []
    for r, ss in enumerate(SeedPlan(seed).runs(n_runs)):
        run = _honest_run(pipe, ss, config.road_spec(), guard)
        honest = [run.message(z) for z in run.z]
        mse_h = _score(run, _secagg_node(run, honest)[0])
        own = run.z[malicious]
        for m in margins:
            bound = m * float(np.sqrt(np.max(np.sum(run.z ** 2, axis=(1, 2)))))
            bad = run.message(-own * bound / float(np.sqrt(np.sum(own ** 2))))
            z, refused = _secagg_node(run, honest[:malicious] + [bad] + honest[malicious + 1:])
            rows.append(BoundedInfluenceRow(r, float(m), _score(run, z) / mse_h, refused))
    return rows
