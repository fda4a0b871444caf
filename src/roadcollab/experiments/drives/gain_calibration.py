"""Per-vehicle IRI gain calibration from the segments vehicles share (crowd-sourced self-calibration).

Why
---
A vehicle inverts the road with its *estimated* half-car parameters (10 % error per parameter in
the simulated fleets). The error is, to first order, a gain over the IRI band: the vehicle's
profile is about ``g_v`` times the truth there (docs/map.md measures 0.95-0.98 correlation at zero
lag and an amplitude of 1.28-1.39 for one vehicle). The IRI is positively homogeneous,
``IRI(c h) = |c| IRI(h)``, so that vehicle's IRI on segment ``s`` is ``g_v I_s``, biased by
-19 % to +26 % per vehicle. Two or three vehicles on a lane keep the mean of their biases;
dividing each vehicle's profile by its gain before fusing removes them.

Model
-----
For every pass of vehicle ``v`` that covers segment ``s`` completely (``I_vs``, m/km)::

    log I_vs = a_s + b_v + e_vs,        a_s = log I_s,  b_v = log g_v,

least squares over every segment driven by at least two vehicles. The vehicle-segment graph splits
into connected components; within one, ``a`` and ``b`` are identified up to one constant (a
common gain of the whole component cannot be seen from its own data). The constant is fixed by
``mean(b_v) = 0`` over the component's *reference* vehicles if it has any (vehicles whose
parameters were identified on a calibration section, ``--reference-vehicle``), otherwise over all of its
vehicles: the assumption that the parameter errors of a fleet do not share a sign. What remains
is then the component's mean log gain, ``sigma_b / sqrt(V)`` in expectation (about 15 % / sqrt(V)
for the simulated fleets), and is stated with every result.

The fit is the equality-constrained least-squares problem solved through its KKT system
(:func:`scipy.linalg.solve`); the covariance of ``b`` is ``s^2`` times the KKT inverse's leading
block, ``s^2`` the residual variance; the interval is ``exp(b +- t_{0.975, dof} se)``.

A vehicle with fewer than ``min_shared`` observations on shared segments (after pruning, repeated
until nothing changes), or alone in its component, keeps gain 1 (status ``"uncalibrated"``).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from typing import Hashable, Iterable

import numpy as np
import scipy.linalg
import scipy.stats

__all__ = ["MIN_SHARED", "VehicleGain", "calibrate_gains"]

#: Observations on shared segments a vehicle needs before its gain is estimated.
MIN_SHARED = 2


@dataclass(frozen=True)
class VehicleGain:
    """One vehicle's IRI gain, a row of ``calibration.csv`` (the fields are its columns, in order).

    Attributes
    ----------
    vehicle_id : str
        The ``vehicle_id`` of its parameters files (or the drive's file when they name none).
    gain : float
        ``g_v``: its IRI (and profile, in the IRI band) over the truth's, dimensionless; its
        profiles are divided by it before fusing. 1 when uncalibrated.
    gain_low, gain_high : float
        95 % interval of ``gain`` (NaN when uncalibrated or without residual degrees of freedom).
    n_segments : int
        Its passes over segments that another vehicle of the fit also covered.
    n_peers : int
        Other vehicles it shares at least one such segment with.
    component : int
        Connected component of the vehicle-segment graph (0, 1, ...; -1 when uncalibrated).
    status : str
        ``"calibrated"``, ``"reference"`` (an anchor of its component) or ``"uncalibrated"``.
    """

    vehicle_id: str
    gain: float
    gain_low: float
    gain_high: float
    n_segments: int
    n_peers: int
    component: int
    status: str


def _prune(obs: dict, min_shared: int) -> dict:
    """``{(v, s): log I}`` keeping segments of >= 2 vehicles and vehicles of >= ``min_shared`` of them."""
    while True:
        by_seg: dict = defaultdict(set)
        for v, s in obs:
            by_seg[s].add(v)
        kept = {k: y for k, y in obs.items() if len(by_seg[k[1]]) >= 2}
        per_v: dict = defaultdict(int)
        for v, _s in kept:
            per_v[v] += 1
        kept = {k: y for k, y in kept.items() if per_v[k[0]] >= min_shared}
        if len(kept) == len(obs):
            return kept
        obs = kept


def _components(obs: dict) -> list[list]:
    """Vehicle sets of the connected components of the vehicle-segment graph (union-find over segments)."""
    parent: dict = {}

    def root(x):
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    first: dict = {}
    for v, s in obs:
        parent.setdefault(v, v)
        if s in first:
            parent[root(v)] = root(first[s])
        else:
            first[s] = v
    groups: dict = defaultdict(list)
    for v in parent:
        groups[root(v)].append(v)
    return sorted((sorted(g) for g in groups.values()), key=lambda g: g[0])


def _fit(obs: dict, vehicles: list, anchors: list) -> tuple[np.ndarray, np.ndarray, int]:
    """log gains ``b`` (V,), their standard errors (V,) and the residual degrees of freedom of one component."""
    segs = sorted({s for _v, s in obs}, key=repr)
    iv, js = {v: i for i, v in enumerate(vehicles)}, {s: i for i, s in enumerate(segs)}
    V, m = len(vehicles), len(obs)
    p = V + len(segs)
    A = np.zeros((m, p))
    y = np.empty(m)
    for r, ((v, s), val) in enumerate(obs.items()):
        A[r, iv[v]] = A[r, V + js[s]] = 1.0
        y[r] = val
    C = np.zeros((1, p))
    C[0, [iv[v] for v in anchors]] = 1.0 / len(anchors)
    K = np.block([[A.T @ A, C.T], [C, np.zeros((1, 1))]])
    theta = scipy.linalg.solve(K, np.concatenate([A.T @ y, [0.0]]), assume_a="sym")[:p]
    dof = m - p + 1
    if dof <= 0:
        return theta[:V], np.full(V, np.nan), dof
    s2 = float(np.sum((y - A @ theta) ** 2)) / dof
    cov = s2 * scipy.linalg.inv(K)[:V, :V]
    return theta[:V], np.sqrt(np.maximum(np.diag(cov), 0.0)), dof


def calibrate_gains(observations: Iterable[tuple[str, Hashable, float]], *, reference: Iterable[str] = (),
                    min_shared: int = MIN_SHARED) -> dict[str, VehicleGain]:
    """Every vehicle's IRI gain from the segments it shares with others (module docstring).

    Parameters
    ----------
    observations : iterable of (vehicle_id, segment, iri)
        One per pass that covers a segment completely: the vehicle, any hashable naming the segment
        (road, direction, from_m), and that pass's own IRI, m/km. Non-positive or non-finite values are
        left out; a vehicle seen twice on one segment counts with the mean of its log IRIs.
    reference : iterable of str
        Vehicles whose gain is 1 by definition (their components' anchors).
    min_shared : int
        Observations on shared segments a vehicle needs.

    Returns
    -------
    dict
        ``{vehicle_id: VehicleGain}`` for every vehicle of ``observations``.
    """
    sums: dict = defaultdict(list)
    everyone: set = set()
    for v, s, val in observations:
        everyone.add(v)
        if math.isfinite(val) and val > 0:
            sums[(v, s)].append(math.log(val))
    obs = _prune({k: float(np.mean(ys)) for k, ys in sums.items()}, min_shared)
    refs = set(reference)
    out = {}
    for c, vehicles in enumerate(_components(obs)):
        sub = {k: y for k, y in obs.items() if k[0] in set(vehicles)}
        anchored = [v for v in vehicles if v in refs]
        anchors = anchored or vehicles
        b, se, dof = _fit(sub, vehicles, anchors)
        t = scipy.stats.t.ppf(0.975, dof) if dof > 0 else float("nan")
        peers: dict = defaultdict(set)
        by_seg: dict = defaultdict(set)
        for v, s in sub:
            by_seg[s].add(v)
        for v, s in sub:
            peers[v] |= by_seg[s] - {v}
        for i, v in enumerate(vehicles):
            out[v] = VehicleGain(v, float(math.exp(b[i])), float(math.exp(b[i] - t * se[i])),
                                 float(math.exp(b[i] + t * se[i])), sum(1 for k in sub if k[0] == v),
                                 len(peers[v]), c, "reference" if v in anchored else "calibrated")
    for v in sorted(everyone - set(out)):
        out[v] = VehicleGain(v, 1.0, float("nan"), float("nan"), 0, 0, -1, "uncalibrated")
    return out
