"""What the replica attacker sees on one of the security study's segments: hardened and DP messages,
the true road and the fleet's fused road (:func:`replica_messages`). The attacks themselves, single
messages and linked segments, are run and scored by :mod:`~roadcollab.experiments.security.replica`.

Segment ``r`` uses the security study's seed of run ``r`` (``SeedPlan(seed).runs(n)[r]``, as
``roadcollab attack``) and its named streams: the road (the same roads as ``roadcollab attack``), the sensor
noise and the Gaussian-mechanism noise, drawn vehicle by vehicle in fleet order. For every vehicle
``j < n_targets``:

- ``hardened``: its ``z = W_reg P_hat^-1 y`` (what any exact relay hands the receiver);
- ``dp(eps=e)``: that ``z`` plus the Gaussian mechanism calibrated per message for ``e`` (the ``dp``
  baseline).

Roads: ``true`` (the road velocity the vehicle drove) and ``fused`` (no true road: the fleet's
published road map, the average of the *other* vehicles' posterior inversions of their records, as the
``fused_posterior`` exchange computes it, cut to the recorded ``N`` samples).
"""

from __future__ import annotations

import numpy as np

from ..._validation import check_int
from ...models.simulation import add_sensor_noise, simulate_response
from ...privacy.baselines.dp import gaussian_sigma, l2_sensitivity
from .segment import target_poles
from ..pipeline import PipelineCache
from .config import AttackStudyConfig
from ..seeds import SeedPlan, run_stream

__all__ = ["replica_messages"]

def _mechanisms(epsilons) -> tuple[str, ...]:
    """``hardened`` and one ``dp(eps=e)`` per level."""
    return ("hardened",) + tuple(f"dp(eps={e:g})" for e in epsilons)


# Long: one segment's messages and roads for every mechanism, drawn stream by stream in fleet order.
def replica_messages(config: AttackStudyConfig, seed: int, run: int, *, epsilons=None, n_targets: int = 3,
                     pipe=None) -> dict:
    """What the replica attacker sees on one segment of the security study.

    Parameters
    ----------
    config : AttackStudyConfig
        The study (fleet, road, sensors, DP delta and rho).
    seed : int
        Root seed (>= 0).
    run : int
        Segment number (>= 0): its seed is the study's seed of that run.
    epsilons : sequence of float, optional
        Per-message DP levels (default ``config.dp_epsilons``).
    n_targets : int
        Vehicles attacked: the first ``n_targets`` of the fleet (>= 1).
    pipe : FleetPipeline, optional
        The study's pipeline (default: built from ``config`` and ``seed``).

    Returns
    -------
    dict
        ``"z"``: ``{mechanism: [z_j (nfft, 2) m/s per target]}``; ``"road"``: ``{"true": [(N, 2)], "fused":
        [(N, 2)]}`` road velocity per target, m/s; ``"grid"``, ``"targets"`` (poles per target, rad/s),
        ``"sigmas"`` (``{epsilon: sigma}``, m/s), ``"z_all"`` (every vehicle's ``z``, (V, nfft, 2) m/s) and
        ``"post_all"`` (every vehicle's posterior inversion, the same shape).
    """
    seed = check_int("seed", seed, low=0)
    run = check_int("run", run, low=0)
    pipe = PipelineCache().pipeline(config.experiment, seed) if pipe is None else pipe
    n_targets = check_int("n_targets", n_targets, low=1, high=len(pipe.estimators))
    eps = tuple(config.dp_epsilons if epsilons is None else epsilons)
    grid, ests = pipe.grid, pipe.estimators
    rs = SeedPlan(seed).runs(run + 1)[run]    # the study's seed of run ``run`` (as ``_run_seeds``)
    road_rng, noise_rng, dp_rng = (np.random.default_rng(run_stream(rs, name)) for name in ("road", "noise", "dp"))
    w = pipe.road(road_rng).velocity
    noise = config.experiment.sensor_noise_std
    Ys = [grid.rfft(add_sensor_noise(simulate_response(e.true_plant, w), noise, rng=noise_rng)) for e in ests]
    sens = l2_sensitivity(ests[0], config.dp_rho)
    sigmas = {e: gaussian_sigma(e, config.dp_delta, sens) for e in eps}
    z_all = np.array([grid.irfft(e.invert(Y)) for e, Y in zip(ests, Ys)])
    z_hard = list(z_all[:n_targets])
    zs = {"hardened": z_hard}
    for e, mech in zip(eps, _mechanisms(eps)[1:]):
        zs[mech] = [z + sigmas[e] * dp_rng.standard_normal(z.shape) for z in z_hard]
    post = [grid.irfft(e.invert(Y, posterior=True)) for e, Y in zip(ests, Ys)]
    total = np.sum(post, axis=0)
    fused = [((total - post[j]) / (len(ests) - 1))[:grid.n_samples] for j in range(n_targets)]
    return {"z": zs, "road": {"true": [w] * n_targets, "fused": fused}, "grid": grid,
            "targets": target_poles(pipe)[:n_targets], "sigmas": sigmas, "z_all": z_all, "post_all": np.array(post)}
