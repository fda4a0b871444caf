"""Band-limited road-velocity estimates of every vehicle on one run, for applications.

The same engine as :func:`roadcollab.experiments.reproduction.study.simulate_run` (road, sensor noise
and the relays of Algorithm 1 and the fleet average), without the privacy chain, which changes
no estimate. The anomaly study and its calibration detect anomalies in these estimates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import check_nonnegative
from ...collaboration.relay import Relay
from ...models.profile import TimeRoad
from ...models.road import RoadSpec
from ..pipeline import FleetPipeline, record_run
from ..seeds import as_seed_sequence, run_stream

__all__ = ["RunEstimates", "run_estimates"]


@dataclass(frozen=True, eq=False)
class RunEstimates:
    """Band-limited road-velocity estimates of every vehicle on one run (for applications).

    Attributes
    ----------
    road : TimeRoad
        The road of the run (ground-truth anomalies in ``road.anomalies``).
    truth : (N, 2) ndarray
        Band-limited true road velocity over the recorded window, m/s.
    observer_only, collaborative, fused : (V, N, 2) ndarray
        Band-limited estimates per vehicle, m/s: own observer, Algorithm 1, running fleet
        average of the inversions ``z``.
    scored : slice
        Samples of the scored segment inside the window.
    positions : (N,) ndarray
        Road distance of each sample, m.
    """

    road: TimeRoad
    truth: np.ndarray
    observer_only: np.ndarray
    collaborative: np.ndarray
    fused: np.ndarray
    scored: slice
    positions: np.ndarray


def run_estimates(pipe: FleetPipeline, rng, *, sensor_noise_std: float | None = None,
                  road_spec: RoadSpec | None = None) -> RunEstimates:
    """Estimates of every vehicle on one run (no privacy chain: it changes no estimate).

    Parameters
    ----------
    pipe : FleetPipeline
    rng : numpy.random.Generator | int | numpy.random.SeedSequence
    sensor_noise_std : float, optional
        Override the configuration's accelerometer noise (m/s^2) for this run, e.g. for a
        noise sweep with estimators designed for the nominal noise.
    road_spec : RoadSpec, optional
        Road condition other than the configuration's, e.g. every anomaly of one depth
        (:meth:`~roadcollab.experiments.pipeline.FleetPipeline.road`).

    Returns
    -------
    RunEstimates
    """
    cfg, grid = pipe.config, pipe.grid
    ss = as_seed_sequence(rng)
    road_ss, noise_ss = run_stream(ss, "road"), run_stream(ss, "noise")
    std = cfg.sensor_noise_std if sensor_noise_std is None else check_nonnegative("sensor_noise_std",
                                                                                  sensor_noise_std)
    road, ys, Ys = record_run(pipe, road_ss, noise_ss, std, road_spec)
    n = grid.n_samples
    w = road.velocity
    plain = Relay(pipe.estimators, "none", unguarded=True).run(ys, spectra=Ys)
    fused = Relay(pipe.estimators, "fused").run(ys, spectra=Ys)

    def band(X):
        return grid.band_limited(X, n)

    return RunEstimates(road=road, truth=band(grid.rfft(w)),
                        observer_only=np.array([band(s.result.W_obs) for s in plain]),
                        collaborative=np.array([band(s.result.W_hat) for s in plain]),
                        fused=np.array([band(s.estimate_spectrum) for s in fused]), scored=cfg.scored,
                        positions=road.positions[:n])
