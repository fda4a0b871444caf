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
from typing import Any

import numpy as np

from ..._validation import check_int
from ...collaboration.guard import ReceiverGuard
from ...detection.scoring import lost_anomalies, new_false_detections
from ..anomalies.config import AnomalyStudyConfig
from .fusion_poisoning import FUSION_STRATEGIES, _attack, _honest_run, _reported, _score, _secagg_node
from ..pipeline import FleetPipeline, fleet_and_run_seeds
from ..seeds import SeedPlan, run_stream

__all__ = ["BoundedInfluenceRow", "bounded_influence_ceiling", "RelativeBoundRow", "relative_bound_ceiling"]


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


@dataclass(frozen=True)
class RelativeBoundRow:
    """One strategy at one ball size of :func:`relative_bound_ceiling`, over the runs.

    Attributes
    ----------
    kappa2 : float
        ``kappa'^2``: the ball's squared radius per band over ``E_b``.
    strategy : str
    ratio : float
        Mean over runs of attacked over honest MSE of vehicle 1's guarded estimate.
    fake, lost : int
        Fake anomalies reported and real anomalies lost, summed over runs.
    honest_refused : int
        Honest inputs outside the ball (in the honest and the attacked sessions), summed over runs.
    max_honest_ratio : float
        Largest honest ``D_b / E_b`` seen.
    """

    kappa2: float
    strategy: str
    ratio: float
    fake: int
    lost: int
    honest_refused: int
    max_honest_ratio: float


def relative_bound_ceiling(config: AnomalyStudyConfig, seed: int, *, n_runs: int = 4, malicious: int = 4,
                           kappa2=(2.0, 9.0)) -> list[RelativeBoundRow]:
    """An ideal check of each input's deviation from the others (not built; docs/security-secagg.md).

    An input is accepted if, per guard band ``b``, its squared l2 distance ``D_b`` to the coordinate-wise
    median spectrum of all inputs is at most ``kappa'^2 E_b`` (``E_b = sum_{k in b} tr C_k``, the public
    expected inversion error, the largest over the fleet); the malicious vehicle sends its strategy
    projected into that ball. The mean of the accepted inputs goes through vehicle 1's guard.

    Parameters
    ----------
    config : AnomalyStudyConfig
    seed : int
    n_runs : int
    malicious : int
    kappa2 : sequence of float

    Returns
    -------
    list of RelativeBoundRow
    """
    n_runs = check_int("n_runs", n_runs, low=1)
    exp = config.experiment
    pipe = FleetPipeline(exp, fleet_and_run_seeds(exp, seed)[0])
    g, act = pipe.grid, pipe.grid.active
    guard = ReceiverGuard(pipe.estimators[0], pipe.road_moment, exp.sensor_noise_std)
    guards = [guard] + [ReceiverGuard(e, pipe.road_moment, exp.sensor_noise_std) for e in pipe.estimators[1:]]
    C = np.max([np.real(np.einsum("ktt->k", gd._inversion_error(pipe.road_moment))) for gd in guards], axis=0)
    E = np.array([C[b].sum() for b in guard.bands])

    acc: dict = {}
    worst = 0.0
    for ss in SeedPlan(seed).runs(n_runs):
        run = _honest_run(pipe, ss, config.road_spec(), guard)
        honest = [run.message(z) for z in run.z]
        Zs = [g.rfft(z) for z in run.z]
        med = np.median(np.real(Zs), axis=0) + 1j * np.median(np.imag(Zs), axis=0)
        worst = max(worst, max(float(np.max(_band_dist(Z, med, act, guard.bands) / E)) for Z in Zs))
        for k2 in kappa2:
            rng = np.random.default_rng(run_stream(ss, "privacy"))
            zh, hr = _ball_node(run, honest, pipe, E, k2)
            rep_h, mse_h = _reported("secagg_guarded", run, zh, run.own), _score(run, zh)
            for s in FUSION_STRATEGIES:
                zm, count, _ = _attack(s, run, malicious, rng)
                msgs = honest[:malicious] + [run.message(zm, count)] + honest[malicious + 1:]
                own = run.own[:malicious] + [run.detect(zm)] + run.own[malicious + 1:]
                zf, h = _ball_node(run, msgs, pipe, E, k2, bad=malicious)
                rep = _reported("secagg_guarded", run, zf, own)
                road: Any = run.road
                acc.setdefault((k2, s), []).append((_score(run, zf) / mse_h,
                                                    new_false_detections(rep, rep_h, road.anomalies, tolerance=1.0),
                                                    lost_anomalies(rep, rep_h, road.anomalies, tolerance=1.0),
                                                    hr + h))
    return [RelativeBoundRow(float(k2), s, float(np.mean([v[0] for v in vals])), int(sum(v[1] for v in vals)),
                             int(sum(v[2] for v in vals)), int(sum(v[3] for v in vals)), worst)
            for (k2, s), vals in acc.items()]


def _band_dist(Z, ref, act, bands) -> np.ndarray:
    """Squared l2 distance of two spectra per band, both tracks, (n_bands,)."""
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.sum(np.abs(Z[act] - ref[act]) ** 2, axis=1)
    return np.array([d[b].sum() for b in bands])


def _ball_node(run, msgs, pipe, E, k2, bad=None) -> tuple[np.ndarray, int]:
    """The ideal deviation check of :func:`relative_bound_ceiling`, then vehicle 1's guard; honest refusals."""
    g, act, bands = pipe.grid, pipe.grid.active, run.receiver_guard().bands
    Zs = [g.rfft(m.z) for m in msgs]
    with np.errstate(over="ignore", invalid="ignore"):
        med = np.median(np.real(Zs), axis=0) + 1j * np.median(np.imag(Zs), axis=0)
    out, refused = [], 0
    for i, Z in enumerate(Zs):
        if not np.all(np.isfinite(Z)):
            continue
        f = np.minimum(1.0, np.sqrt(k2 * E / np.maximum(_band_dist(Z, med, act, bands), 1e-300)))
        if i == bad:                      # the attacker projects into the ball
            Za = Z[act]
            for b, fb in zip(bands, f):
                Za[b] = med[act][b] + (Za[b] - med[act][b]) * fb
            Z = Z.copy()
            Z[act] = Za
        elif np.any(f < 1):
            refused += 1
            continue
        out.append(Z)
    agg = g.irfft(np.mean(out, axis=0))
    est = pipe.estimators[0]
    Zg, _ = run.receiver_guard().substitute(run.message(agg, len(out)), run.Ys[0], est.invert(run.Ys[0], posterior=True))
    return g.irfft(Zg), refused
