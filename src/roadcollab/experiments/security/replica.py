"""The strongest attacker and secure aggregation, measured on the security study's segments.

The replica attacker (:mod:`roadcollab.privacy.replica`) re-runs the receiver's pipeline and fits the
sender's model to what a message hands it. Per mechanism:

- ``none``, ``paper``, ``paper_vehicle``, ``hardened``: every exact relay hands the receiver the
  sender's ``z = W P_hat^-1 y`` (Theorem 1 with the optimal filters; ``exactness.csv``), so one set of
  fits on ``z`` scores all four. Roads: ``true`` and ``fused`` (the fleet's published map: the
  average of the *other* vehicles' posterior inversions); one message and 3 linked segments.
- ``dp(eps=e)``: ``z`` plus the Gaussian mechanism, true road; linked rows carry the composed epsilon.
- ``fused`` (``fused_posterior``): vehicle ``j``'s relayed message is the average of vehicles ``1..j``'s
  ``z`` (posterior inversions).
- ``secure_aggregation``: the aggregator learns the average of all ``n`` inputs (exact to the
  fixed-point resolution); with ``c`` colluding vehicles it learns the average of the other
  ``n - c``. The protocol enforces ``k`` *inputs*, not ``k`` *honest* inputs: with ``c = n - 1``
  colluders the last honest input is exposed, shown as its own row. Rows ``differencing``,
  ``equivocation``, ``sybil`` and ``key_substitution``: an active aggregator against the active protocol
  (:mod:`.secagg_attacks`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..._validation import check_int
from ...privacy.attacks import pole_errors
from ...privacy.baselines.dp import gaussian_sigma
from ...privacy.baselines.dp_composition import composed_epsilon
from ...privacy.replica import replica_fit
from ...privacy.secagg_messages import SecAggSpec
from ...privacy.secagg_active_run import active_secure_aggregation_cost
from ...privacy.secagg_run import secure_aggregation_cost
from .replica_study import replica_messages
from .config import AttackStudyConfig
from .secagg_attacks import active_spec, secagg_attack_rows
from .rows import AttackRow, attack_row

__all__ = ["EXACT_RELAYS", "ReplicaOutcome", "replica_fit_count", "run_replica_attacks"]

#: Mechanisms whose receiver can compute the sender's ``z`` exactly (the replica fits are shared).
EXACT_RELAYS = ("none", "paper", "paper_vehicle", "hardened")
_LINK = 3
_MAX_NFEV = 200


@dataclass(frozen=True, eq=False)
class ReplicaOutcome:
    """Replica attack rows and the secure-aggregation measurements of the study.

    Attributes
    ----------
    rows : tuple of AttackRow
    secagg_exactness : float
        Largest relative difference between the securely aggregated average (active protocol) and the
        plain average of the same inputs (with and without dropouts).
    secagg_clipped : bool
        Whether any honest input reached the clipping bound (exactness then fails by design).
    mse : dict
        Receivers' road-velocity MSE, (m/s)^2: ``"fused"`` and ``"fused_posterior"`` (vehicles 2..3 of
        the relayed averages) and ``"secure_aggregation"`` (the average of all vehicles).
    secagg_cost : dict
        :func:`~roadcollab.privacy.secagg_active_run.active_secure_aggregation_cost` of one segment (with
        the dropouts), and under ``semi_honest`` the
        :func:`~roadcollab.privacy.secagg_run.secure_aggregation_cost` of the semi-honest protocol.
    spec : SecAggSpec
    """

    rows: tuple[AttackRow, ...]
    secagg_exactness: float
    secagg_clipped: bool
    mse: dict
    secagg_cost: dict
    spec: SecAggSpec


def _errors(fit_inputs, targets, grid, nominal, tick) -> list[np.ndarray]:
    """Relative pole errors of one replica fit per ``(segments, target index)``."""
    out = []
    for segments, j in fit_inputs:
        poles = replica_fit(segments, grid, nominal, max_nfev=_MAX_NFEV if len(segments) == 1
                            else int(1.5 * _MAX_NFEV)).poles
        out.append(pole_errors(poles, targets[j]))
        tick()
    return out


def _cells(config: AttackStudyConfig, n: int, T: int, R: int) -> list[tuple]:
    """(mechanism, attack, road, L, z(seg, j), target indices, composed epsilon) of every fitted cell."""
    eps = tuple(config.dp_epsilons)
    cells: list[tuple] = [("hardened", "replica", road, 1, lambda s, j: s["z"]["hardened"][j], range(T), np.nan)
             for road in ("true", "fused")]
    if R >= _LINK:
        cells += [("hardened", "replica_linked", road, _LINK, lambda s, j: s["z"]["hardened"][j], range(T), np.nan)
                  for road in ("true", "fused")]
    for e in eps:
        m = gaussian_sigma(e, config.dp_delta, 1.0)
        key = f"dp(eps={e:g})"
        cells.append((key, "replica", "true", 1, lambda s, j, k=key: s["z"][k][j], range(T),
                      composed_epsilon(m, 1, config.dp_delta)))
        if R >= _LINK and e in (min(eps), max(eps)):
            cells.append((key, "replica_linked", "true", _LINK, lambda s, j, k=key: s["z"][k][j], range(T),
                          composed_epsilon(m, _LINK, config.dp_delta)))
    cells.append(("fused", "replica", "true", 1, lambda s, j: s["z_all"][:j + 1].mean(axis=0), range(T), np.nan))
    # The replica model inverts the nominal plant; fitting it to a posterior inversion is the attacker's
    # approximation (the posterior mean plant has no closed form in theta_hat).
    cells.append(("fused_posterior", "replica", "true", 1, lambda s, j: s["post_all"][:j + 1].mean(axis=0), range(T),
                  np.nan))
    agg = lambda s, j: s["z_all"].mean(axis=0)  # noqa: E731
    cells.append(("secure_aggregation", "replica", "true", 1, agg, range(T), np.nan))
    if R >= _LINK:
        cells.append(("secure_aggregation", "replica_linked", "true", _LINK, agg, range(T), np.nan))
    for c in sorted(set(config.secagg_colluders or ()) | {n - 1}):     # filled in by __post_init__
        cells.append(("secure_aggregation", f"replica_collusion_c{c}", "true", 1,
                      lambda s, j, c=c: s["z_all"][:n - c].mean(axis=0), range(min(T, n - c)), np.nan))
    return cells


def replica_fit_count(config: AttackStudyConfig) -> int:
    """Replica fits :func:`run_replica_attacks` makes (for a progress bar).

    Parameters
    ----------
    config : AttackStudyConfig

    Returns
    -------
    int
    """
    R = config.replica_runs
    return sum((R // c[3]) * len(c[5]) for c in _cells(config, config.experiment.n_vehicles,
                                                        config.replica_targets, R))


def _fit_inputs(cell, segs) -> list[tuple[list, int]]:
    """``[(segments [(z, road)], target index)]`` of one cell: single messages or linked groups."""
    _, _, road, L, get, targets, _ = cell
    groups = [segs[g * L:(g + 1) * L] for g in range(len(segs) // L)]
    return [([(get(s, j), s["road"][road][j]) for s in grp], j) for grp in groups for j in targets]


def _secagg(config: AttackStudyConfig, seg: dict, seed: int) -> tuple[float, bool, dict, SecAggSpec]:
    """The active protocol on one segment: exactness (no dropout; dropouts after the key round up to
    ``n - k``, at most 2), clipping and cost (the semi-honest cost is kept as ``semi_honest``)."""
    z = seg["z_all"]
    n = z.shape[0]
    spec = active_spec(n)
    worst = 0.0
    for dropped in ((), tuple(range(n, max(n - 2, spec.min_inputs), -1))):
        cost = active_secure_aggregation_cost(list(z), spec, repeats=3, dropped=dropped, rng=seed)
        worst = max(worst, cost["max_rel_error"])
    k = check_int("secagg_min_inputs", config.secagg_min_inputs)       # filled in by __post_init__
    legacy = SecAggSpec(min_inputs=k, threshold=k)
    cost["semi_honest"] = secure_aggregation_cost(z[0], n_vehicles=n, spec=legacy, repeats=3, rng=seed)
    return worst, bool(np.max(np.abs(z)) >= spec.clip), cost, spec


def _mse(pipe, segs) -> dict:
    """Receivers' MSE of the relayed average (vehicles 2..3) and of the aggregate of all vehicles."""
    g, sl = pipe.grid, pipe.config.scored
    n = g.n_samples
    fused, post, agg = [], [], []
    for s in segs:
        truth = g.band_limited(g.rfft(s["road"]["true"][0]), n)[sl]
        z, zp = s["z_all"], s["post_all"]
        fused += [np.mean((z[:j + 1].mean(axis=0)[:n][sl] - truth) ** 2) for j in (1, 2) if j < len(z)]
        post += [np.mean((zp[:j + 1].mean(axis=0)[:n][sl] - truth) ** 2) for j in (1, 2) if j < len(z)]
        agg.append(np.mean((z.mean(axis=0)[:n][sl] - truth) ** 2))
    return {"fused": float(np.mean(fused)), "fused_posterior": float(np.mean(post)),
            "secure_aggregation": float(np.mean(agg))}


def run_replica_attacks(config: AttackStudyConfig, seed: int, pipe, *,
                        progress: Callable[[int], None] | None = None) -> ReplicaOutcome:
    """Every replica cell of the study and the secure-aggregation measurements.

    Parameters
    ----------
    config : AttackStudyConfig
        ``replica_runs`` segments, ``replica_targets`` vehicles attacked.
    seed : int
        Root seed (the segments are the study's first ``replica_runs`` runs).
    pipe : FleetPipeline
        The study's pipeline.
    progress : callable, optional
        Called with the number of fits done so far.

    Returns
    -------
    ReplicaOutcome
    """
    R, T, n = config.replica_runs, config.replica_targets, config.experiment.n_vehicles
    segs = [replica_messages(config, seed, r, n_targets=T, pipe=pipe) for r in range(R)]
    grid, targets, nominal = segs[0]["grid"], segs[0]["targets"], config.experiment.fleet.nominal
    done = [0]

    def tick():
        done[0] += 1
        if progress is not None:
            progress(done[0])

    rows, agg_errors = [], []
    for cell in _cells(config, n, T, R):
        mech, attack, road, L, _, _, eps_total = cell
        errs = _errors(_fit_inputs(cell, segs), targets, grid, nominal, tick)
        if not errs:
            continue
        mechs = EXACT_RELAYS if mech == "hardened" else (mech,)
        rows += [attack_row(m, attack, road, L, errs, eps_total) for m in mechs]
        if (mech, attack) == ("secure_aggregation", "replica"):
            agg_errors = errs
    # The active aggregator's attacks (issue 20): what it recovers, else the aggregate's fit above.
    rows += secagg_attack_rows(segs, T, agg_errors, lambda z, road, j: _errors(
        [([(z, road)], j)], targets, grid, nominal, lambda: None)[0], seed)
    exact, clipped, cost, spec = _secagg(config, segs[0], seed)
    return ReplicaOutcome(tuple(rows), exact, clipped, _mse(pipe, segs), cost, spec)
