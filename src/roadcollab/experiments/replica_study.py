"""The replica attack measured on the security study's segments: hardened and DP messages, the true
road and the fleet's fused road, single messages and linked segments.

Segment ``r`` uses the security study's seed of run ``r`` (``SeedPlan(seed).runs(n)[r]``, as
``roadcollab attack``) and its named streams: the road (the same roads as ``roadcollab attack``), the sensor
noise and the Gaussian-mechanism noise, drawn vehicle by vehicle in fleet order. Every vehicle
``j < n_targets`` is attacked:

- ``hardened``: its ``z = W_reg P_hat^-1 y`` (what any exact relay hands the receiver);
- ``dp(eps=e)``: that ``z`` plus the Gaussian mechanism calibrated per message for ``e`` (the ``dp``
  baseline); for linked segments the row also gives the *composed* epsilon of that many messages
  (:func:`~roadcollab.privacy.baselines.dp_composition.composed_epsilon`, PLD accountant).

Roads: ``true`` (the road velocity the vehicle drove) and ``fused`` (no true road: the fleet's
published road map, the average of the *other* vehicles' posterior inversions of their records, as the
``fused_posterior`` exchange computes it, cut to the recorded ``N`` samples). Segments: 1 (each message
alone) or ``L`` consecutive segments of the same vehicle linked (one ``theta_hat`` fitted to all).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from .._validation import check_int
from ..errors import ParameterError
from ..models.simulation import add_sensor_noise, simulate_response
from ..privacy.attacks import pole_errors
from ..privacy.baselines.dp import gaussian_sigma, l2_sensitivity
from ..privacy.baselines.dp_composition import composed_epsilon
from ..privacy.replica import replica_fit
from .security_segment import target_poles
from .pipeline import PipelineCache
from .security_config import AttackStudyConfig
from .security_rows import attack_row
from .seeds import SeedPlan, run_stream

__all__ = ["ReplicaRow", "ReplicaStudyResult", "run_replica_study", "replica_messages"]

#: Roads the attacker may assume.
ROADS = ("true", "fused")


@dataclass(frozen=True)
class ReplicaRow:
    """One (mechanism, attack, road, segments) cell of the replica study.

    Parameters
    ----------
    mechanism : str
        ``"hardened"`` or ``"dp(eps=e)"`` (per-message level).
    attack : str
        ``"replica"`` (one message) or ``"replica_linked"``.
    road : str
        ``"true"`` or ``"fused"``.
    segments : int
        Messages of one vehicle per fit.
    median_rel_pole_error : float
        Median over fits of the median relative pole error.
    success_rate : float
        Fraction of fits with every pole within :data:`~roadcollab.privacy.attacks.SUCCESS_TOLERANCE`.
    n_messages : int
        Fits scored.
    epsilon_total : float
        DP rows: total epsilon of ``segments`` composed messages (PLD accountant, same delta); NaN otherwise.
    median_seconds : float
        Median wall-clock time of one fit, s.
    """

    mechanism: str
    attack: str
    road: str
    segments: int
    median_rel_pole_error: float
    success_rate: float
    n_messages: int
    epsilon_total: float
    median_seconds: float


@dataclass(frozen=True)
class ReplicaStudyResult:
    """The replica study's rows, in the order measured.

    Parameters
    ----------
    rows : tuple of ReplicaRow
        One per (mechanism, attack, road, segments).
    """

    rows: tuple[ReplicaRow, ...]

    def to_rows(self) -> list[dict]:
        """The rows as dicts (keys: the fields of :class:`ReplicaRow`).

        Returns
        -------
        list of dict
        """
        return [asdict(r) for r in self.rows]


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


def _score(fits: list[tuple[np.ndarray, float]], targets: list[np.ndarray]) -> tuple[float, float, int, float]:
    """(median of per-fit median error, success rate, fits, median seconds) of ``[(poles, seconds)]``."""
    row = attack_row("", "", "", 1, [pole_errors(p, t) for (p, _), t in zip(fits, targets)])
    return row.median_rel_pole_error, row.success_rate, row.n_messages, float(np.median([s for _, s in fits]))


def _timed_fit(segments, grid, nominal, max_nfev: int) -> tuple[np.ndarray, float]:
    """Poles of one replica fit and its wall-clock time, s."""
    t0 = time.perf_counter()
    poles = replica_fit(segments, grid, nominal, max_nfev=max_nfev).poles
    return poles, time.perf_counter() - t0


# Long: the study's loop over mechanisms x roads x linking, each scored into one row.
def run_replica_study(config: AttackStudyConfig, seed: int, *, n_runs: int = 3, n_targets: int = 3, epsilons=None,
                      linked_segments=(3,), max_nfev: int = 200) -> ReplicaStudyResult:
    """Run the replica attack on the study's segments (see the module docstring).

    Parameters
    ----------
    config : AttackStudyConfig
        The security study's configuration (``config.n_runs`` is not used: ``n_runs`` is).
    seed : int
        Root seed (>= 0).
    n_runs : int
        Segments (>= 1); single-message rows score ``n_runs * n_targets`` fits.
    n_targets : int
        Vehicles attacked, the first of the fleet (>= 1).
    epsilons : sequence of float, optional
        Per-message DP levels (default ``config.dp_epsilons``; empty for hardened only).
    linked_segments : sequence of int
        Link lengths ``L`` (>= 2): runs are split into ``n_runs // L`` groups of consecutive segments; a
        length with no complete group is skipped.
    max_nfev : int
        Residual evaluations per fit (linked fits get 1.5x).

    Returns
    -------
    ReplicaStudyResult

    Raises
    ------
    ParameterError
        If ``config`` is not an AttackStudyConfig or a count is out of range.
    """
    if not isinstance(config, AttackStudyConfig):
        raise ParameterError(f"config must be an AttackStudyConfig, got {type(config).__name__}")
    n_runs = check_int("n_runs", n_runs, low=1)
    links = [check_int("linked_segments[]", L, low=2) for L in linked_segments]
    eps = tuple(config.dp_epsilons if epsilons is None else epsilons)
    nominal = config.experiment.fleet.nominal
    pipe = PipelineCache().pipeline(config.experiment, seed)
    segs = [replica_messages(config, seed, r, epsilons=eps, n_targets=n_targets, pipe=pipe) for r in range(n_runs)]
    grid, targets = segs[0]["grid"], segs[0]["targets"]
    per_eps = dict(zip(_mechanisms(eps), (None,) + eps))
    rows = []
    for mech, e in per_eps.items():
        m = None if e is None else gaussian_sigma(e, config.dp_delta, 1.0)
        for road in ROADS:
            fits = [_timed_fit([(s["z"][mech][j], s["road"][road][j])], grid, nominal, max_nfev)
                    for s in segs for j in range(n_targets)]
            score = _score(fits, targets * n_runs)
            rows.append(ReplicaRow(mech, "replica", road, 1, *score[:3],
                                   np.nan if m is None else composed_epsilon(m, 1, config.dp_delta), score[3]))
            for L in links:
                groups = [segs[g * L:(g + 1) * L] for g in range(n_runs // L)]
                if not groups:
                    continue
                fits = [_timed_fit([(s["z"][mech][j], s["road"][road][j]) for s in grp], grid, nominal,
                                   int(1.5 * max_nfev)) for grp in groups for j in range(n_targets)]
                score = _score(fits, targets * len(groups))
                rows.append(ReplicaRow(mech, "replica_linked", road, L, *score[:3],
                                       np.nan if m is None else composed_epsilon(m, L, config.dp_delta), score[3]))
    return ReplicaStudyResult(tuple(rows))
