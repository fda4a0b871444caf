"""The fleet's estimates on the distance grid, read back from the service's store.

The same arrays as :class:`~roadcollab.experiments.drives.fleet_estimation.FleetEstimates` (unaligned): the
grid spans every vehicle's covered stretch (``distance_grid`` of all drives), the vehicles are in the
order of their ids (drive ``k`` is vehicle ``vk``), and ``fused`` is the service's running sums
(:class:`~roadcollab.network.engine.SegmentSums`), i.e. the average of every inversion at each point.

Under secure aggregation the service holds no vehicle's estimates (the contributions are sealed relay
messages, the sums come from the rounds): every per-vehicle array is NaN, the grid spans the points the
rounds covered, and only ``fused`` and ``coverage`` carry numbers.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..errors import ParameterError
from .engine import ESTIMATES
from .messages import SEALED_MAGIC, decode_contribution
from .store import ServiceStore

__all__ = ["NetworkResults", "results_from_store"]


@dataclass(frozen=True, eq=False)
class NetworkResults:
    """Estimates of every vehicle on one uniform distance grid.

    Attributes
    ----------
    vehicles : list of (str, dict)
        ``(vehicle id, its hello)`` in the order of their ids (``v1, v2, ..., v10``).
    position : (n,) ndarray
        m.
    spacing : float
        m.
    elevation : dict
        ``{estimator: (V, n, 2) ndarray}`` for ``single``, ``inversion``, ``collaborative`` and the running
        ``fused`` (vehicles 1..k in id order), m, NaN where not covered.
    fused : (n, 2) ndarray
        The service's fused elevation, m (NaN where no vehicle passed).
    coverage : (n,) ndarray
        Inversions covering each point.
    received_s : dict
        ``{(vid, segment): time the service applied it, s since the epoch}``.
    """

    vehicles: list
    position: np.ndarray
    spacing: float
    elevation: dict
    fused: np.ndarray
    coverage: np.ndarray
    received_s: dict

    def fleet_view(self) -> Any:   # duck-typed: the FleetEstimates attributes those functions read
        """The attributes :func:`~roadcollab.experiments.drives.fleet_estimation.fused_iri` and
        :func:`~roadcollab.experiments.drives.fleet_estimation.find_fleet_anomalies` read (fused elevation, grid,
        each vehicle's mean speed), as a :class:`~roadcollab.experiments.drives.fleet_estimation.FleetEstimates`
        would give them.

        Returns
        -------
        types.SimpleNamespace
        """
        return SimpleNamespace(fused=self.fused, position=self.position, spacing=self.spacing,
                               drives=[SimpleNamespace(speed=float(h["speed_mps"])) for _, h in self.vehicles])


def _natural(vid: str) -> tuple:
    """``v2`` before ``v10``: enroll numbers the vehicles and ``fleet`` gives drive ``k`` to ``vk``."""
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", vid))


def results_from_store(store: ServiceStore) -> NetworkResults:
    """Assemble :class:`NetworkResults` from a store.

    Parameters
    ----------
    store : ServiceStore

    Raises
    ------
    ParameterError
        The store holds no contribution yet.
    """
    plan = store.plan
    rows = store.contributions()
    if not rows:
        raise ParameterError(f"--store {store.path}: no contribution has been applied yet")
    vehicles = sorted(store.vehicles(), key=lambda vh: _natural(vh[0]))
    order = {v: k for k, (v, _) in enumerate(vehicles)}
    if any(d.startswith(SEALED_MAGIC) for _, _, d, _ in rows):
        return _secure_results(store, vehicles, rows)
    contribs = [(v, decode_contribution(d, plan, s), t) for v, s, d, t in rows]
    i_lo = min(c.i0 for _, c, _ in contribs)
    i_hi = max(c.i0 + c.n for _, c, _ in contribs)
    n, V = i_hi - i_lo, len(vehicles)
    elev = {k: np.full((V, n, 2), np.nan) for k in ESTIMATES}
    for v, c, _ in contribs:
        for k in ESTIMATES:
            elev[k][order[v], c.i0 - i_lo:c.i0 - i_lo + c.n] = getattr(c, k)
    inv = elev["inversion"]
    ok = np.isfinite(inv)
    with np.errstate(invalid="ignore", divide="ignore"):
        sums, counts = np.cumsum(np.where(ok, inv, 0.0), axis=0), np.cumsum(ok, axis=0)
        elev["fused"] = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    fused = np.full((n, 2), np.nan)
    coverage = np.zeros(n, dtype=np.int64)
    for s, S in store.fused().items():
        a, b = plan.segment_range(s)
        lo, hi = max(a, i_lo), min(b, i_hi)
        fused[lo - i_lo:hi - i_lo] = S.fused[lo - a:hi - a]
        coverage[lo - i_lo:hi - i_lo] = S.count[lo - a:hi - a]
    return NetworkResults(vehicles=vehicles, position=plan.positions(i_lo, i_hi), spacing=plan.spacing,
                          elevation=elev, fused=fused, coverage=coverage,
                          received_s={(v, c.segment): t for v, c, t in contribs})


def _secure_results(store: ServiceStore, vehicles: list, rows: list) -> NetworkResults:
    plan = store.plan
    sums = store.fused()
    if not sums:
        raise ParameterError(f"--store {store.path}: no secure-aggregation round has finished yet")
    cov = {s: np.flatnonzero(S.count > 0) for s, S in sums.items()}
    idx = [plan.segment_range(s)[0] + c for s, c in cov.items() if c.size]
    if not idx:
        raise ParameterError(f"--store {store.path}: no secure-aggregation round has finished yet")
    i_lo, i_hi = int(min(i.min() for i in idx)), int(max(i.max() for i in idx)) + 1
    n, V = i_hi - i_lo, len(vehicles)
    fused = np.full((n, 2), np.nan)
    coverage = np.zeros(n, dtype=np.int64)
    for s, S in sums.items():
        a, b = plan.segment_range(s)
        lo, hi = max(a, i_lo), min(b, i_hi)
        if hi > lo:
            fused[lo - i_lo:hi - i_lo] = S.fused[lo - a:hi - a]
            coverage[lo - i_lo:hi - i_lo] = S.count[lo - a:hi - a]
    elev = {k: np.full((V, n, 2), np.nan) for k in ESTIMATES + ("fused",)}
    return NetworkResults(vehicles=vehicles, position=plan.positions(i_lo, i_hi), spacing=plan.spacing,
                          elevation=elev, fused=fused, coverage=coverage,
                          received_s={(v, s): t for v, s, _, t in rows})
