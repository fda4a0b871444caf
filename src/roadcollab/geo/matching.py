"""Hidden-Markov-model map matching (Newson & Krumm 2009) and road positions of a drive.

Matching
--------
The hidden state at fix ``t`` is a road candidate ``(road, m)``: the projection of the fix onto a
road within ``radius`` (the closest point, measure ``m``). Newson & Krumm's two probabilities:

.. math::

    p(z_t | r) = \\frac{1}{\\sqrt{2\\pi}\\sigma_z} e^{-\\frac12 (\\|z_t - x_{t,r}\\| / \\sigma_z)^2}, \\qquad
    p(r_{t} \\to r_{t+1}) = \\frac{1}{\\beta} e^{-|d_{\\rm route} - \\|z_t - z_{t+1}\\|| / \\beta}

(their eqs. 1 and 2), ``sigma_z`` the GPS error (m) and ``beta`` the scale of the difference
between the route distance and the straight-line distance of consecutive fixes. The route distance
runs along the roads through the junctions (:meth:`~roadcollab.geo.network.RoadNetwork.route_m`),
so a jump to a parallel road 10 m away costs the detour through the nearest junction, not 10 m:
that, and the emission integrated over many fixes, is what keeps a drive on its road. The most
likely sequence is Viterbi's, in log probabilities. Fixes with no candidate break the chain (the
matcher restarts after them, as Newson & Krumm do).

Why not a package: ``leuvenmapmatching`` (the PyPI HMM matcher) was last released in 2022 and
wants its own graph types; the algorithm is 40 lines over shapely and a junction graph.

Position along the road
-----------------------
The odometer (or integrated speed) of the log is trusted for the *shape* of the position curve; the
fixes give its offset. On the fixes matched to one road, the direction is the sign
of the slope of ``m`` against the odometer, and the offset is the least-squares one,
``m_0 = mean(m_t - s * odo_t)`` (``s = +-1``), after dropping fixes more than 3 ``sigma_z`` from
the first fit. With ``F`` independent fixes of along-road error ``sigma`` it is known to
``sigma / sqrt(F)`` (3 m and 250 fixes: 0.19 m). The existing cross-correlation alignment of the
fleet estimation then removes what is left between drives.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Point

from .._validation import check_real
from ..errors import ParameterError
from ..io.drives import Drive
from .network import RoadNetwork

__all__ = ["MatchedFixes", "RoadPass", "match_fixes", "road_passes", "lonlat_at"]

_LOG_SQRT_2PI = 0.5 * np.log(2 * np.pi)


@dataclass(frozen=True, eq=False)
class MatchedFixes:
    """The most likely road of every fix.

    Attributes
    ----------
    road_id : (F,) object ndarray
        Road of each fix (None where it had no candidate).
    measure : (F,) ndarray
        Its measure on that road, m (NaN where none).
    distance : (F,) ndarray
        Distance from the fix to the road, m (NaN where none).
    """

    road_id: np.ndarray
    measure: np.ndarray
    distance: np.ndarray


@dataclass(frozen=True, eq=False)
class RoadPass:
    """A drive's stretch on one road, in the lane's own coordinate.

    Attributes
    ----------
    road_id : str
    direction : int
        +1 along the road's measure, -1 against it.
    drive : Drive
        The whole record with ``positions`` in the *lane coordinate* ``u`` (increasing): the road
        measure for ``direction = +1``, ``length - measure`` for -1, continued linearly past the
        road's ends (there the vehicle is on other roads; only ``u_range`` is this road).
    n_fixes : int
        Fixes that placed it.
    offset_std : float
        Standard error of the offset, m (residual std / sqrt(n_fixes)).
    u_range : (float, float)
        Lane coordinates of the first and last sample on this road, m; where the drive turns onto or off
        the road through a junction, that end is the junction's lane coordinate.
    """

    road_id: str
    direction: int
    drive: Drive
    n_fixes: int
    offset_std: float
    u_range: tuple


def _candidates(network: RoadNetwork, x: float, y: float, radius: float) -> list[tuple[str, float, float]]:
    pt = Point(x, y)
    out = []
    for rid, road in network.roads.items():
        d = float(road.line.distance(pt))
        if d <= radius:
            out.append((rid, float(road.line.project(pt)), d))
    return out


def match_fixes(network: RoadNetwork, lon, lat, *, sigma_z: float = 5.0, beta: float = 5.0,
                radius: float = 50.0) -> MatchedFixes:
    """Viterbi map matching of one drive's fixes (module docstring).

    Parameters
    ----------
    network : RoadNetwork
    lon, lat : (F,) array_like
        Fixes, WGS 84 degrees.
    sigma_z : float
        GPS error standard deviation, m (Newson & Krumm estimated 4.07 m).
    beta : float
        Route-versus-straight-line difference scale, m.
    radius : float
        Roads farther from a fix than this are not candidates, m.

    Returns
    -------
    MatchedFixes
    """
    for name, v in (("sigma_z", sigma_z), ("beta", beta), ("radius", radius)):
        check_real(name, v, low=0.0, low_open=True)
    x, y = network.projection.to_xy(lon, lat)
    F = x.shape[0]
    cands = [_candidates(network, x[t], y[t], radius) for t in range(F)]
    road = np.full(F, None, dtype=object)
    meas, dist = np.full(F, np.nan), np.full(F, np.nan)
    score: np.ndarray | None = None
    back: list[tuple[int, np.ndarray] | None] = [None] * F
    prev: int | None = None
    for t in range(F):
        if not cands[t]:
            score, prev = None, None
            continue
        emit = np.array([-0.5 * (d / sigma_z) ** 2 - _LOG_SQRT_2PI - np.log(sigma_z) for _, _, d in cands[t]])
        if score is None or prev is None:             # the chain starts (score and prev are set together)
            score, back[t] = emit, None
        else:
            gc = float(np.hypot(x[t] - x[prev], y[t] - y[prev]))
            trans = np.array([[-abs(network.route_m(ra, ma, rb, mb) - gc) / beta - np.log(beta)
                               for rb, mb, _ in cands[t]] for ra, ma, _ in cands[prev]])
            total = score[:, None] + trans
            best = np.argmax(total, axis=0)
            new = total[best, np.arange(len(cands[t]))] + emit
            if not np.any(np.isfinite(new)):          # unreachable: break the chain here
                score, back[t] = emit, None
            else:
                score, back[t] = new, (prev, best)
        prev = t
        if t == F - 1 or not cands[t + 1]:
            _backtrack(cands, back, t, int(np.argmax(score)), road, meas, dist)
    return MatchedFixes(road_id=road, measure=meas, distance=dist)


def _backtrack(cands, back, t, k, road, meas, dist) -> None:
    """Write the Viterbi path ending in candidate ``k`` of fix ``t`` into the output arrays."""
    while t is not None:
        road[t], meas[t], dist[t] = cands[t][k]
        if back[t] is None:
            return
        t, ks = back[t][0], back[t][1]
        k = int(ks[k])


def _offset(m: np.ndarray, odo: np.ndarray, s: int, sigma_z: float) -> tuple[float, float]:
    """Least-squares offset ``m0`` of ``m = m0 + s odo``, refit without 3-sigma outliers; and its std error."""
    r = m - s * odo
    m0 = float(np.mean(r))
    keep = np.abs(r - m0) <= 3 * sigma_z
    if np.count_nonzero(keep) >= 2:
        r = r[keep]
        m0 = float(np.mean(r))
    return m0, float(np.std(r) / np.sqrt(r.shape[0]))


def road_passes(drive: Drive, network: RoadNetwork, *, sigma_z: float = 5.0, min_length: float = 50.0,
                min_fixes: int = 5) -> list[RoadPass]:
    """Cut a drive with GPS fixes into its passes over the roads of ``network`` (module docstring).

    Parameters
    ----------
    drive : Drive
        With ``gps`` fixes; its ``positions`` (odometer or integrated speed) give the shape.
    network : RoadNetwork
    sigma_z : float
        GPS error standard deviation, m.
    min_length : float
        Passes shorter than this are dropped, m.
    min_fixes : int
        Runs of fewer matched fixes are dropped.

    Returns
    -------
    list of RoadPass
        In driving order.

    Raises
    ------
    ParameterError
        The drive has no GPS fixes.
    """
    if drive.gps is None:
        raise ParameterError(f"{drive.csv_path}: expected lat_deg, lon_deg columns (GPS fixes) to place the drive "
                             "on the road network")
    g = drive.gps
    matched = match_fixes(network, g.lon, g.lat, sigma_z=sigma_z)
    odo_all = drive.positions - drive.positions[0]
    odo = np.interp(g.time, drive.time, odo_all)
    out = []
    for rid, first, last, lo, hi in _split_turns(_road_runs(matched.road_id, min_fixes), matched, odo, min_fixes,
                                                 sigma_z):
        # one pass per contiguous run of fixes on a road: a drive that comes back to a road (a loop, a
        # U-turn) passes it again, with its own direction and offset
        sel = np.zeros(len(odo), dtype=bool)
        sel[first:last + 1] = matched.road_id[first:last + 1] == rid
        m, o = matched.measure[sel], odo[sel]
        s = 1 if np.polyfit(o, m, 1)[0] >= 0 else -1
        m0, err = _offset(m, o, s, sigma_z)
        length = network.roads[rid].length
        meas = m0 + s * odo_all
        # lane coordinate of every sample of the whole record (continued past the road's ends, where
        # the drive is on other roads): the inversion runs on the whole record, free of cut edges
        u = meas if s > 0 else length - meas
        # on the road between the fixes of the runs before and after this one (another pass of the same
        # road has its own samples); a turn onto or off this road through a junction happens at the junction: there the cut is the
        # junction's lane coordinate (exact to the offset's error), not the neighbouring run's nearest fix
        between = np.ones(odo_all.shape, dtype=bool)
        ends: list[float | None] = [None, None]           # the junctions' lane coordinates where cut there
        for k, after in ((lo, False), (hi, True)):
            if k is None:
                continue
            uj = _junction_u(network, rid, str(matched.road_id[k]), s, m0 + s * odo[k])
            if uj is not None:
                between &= (u <= uj) if after else (u >= uj)
                ends[int(after)] = uj
            else:
                between &= (odo_all < odo[k]) if after else (odo_all > odo[k])
        on = np.flatnonzero((meas >= 0) & (meas <= length) & between)
        if on.size < 64 or np.ptp(u[on]) < min_length:
            continue
        whole = dataclasses.replace(drive, positions=u, start_m=float(u[0]), gps=None)
        out.append(RoadPass(road_id=rid, direction=s, drive=whole, n_fixes=int(np.count_nonzero(sel)), offset_std=err,
                            u_range=(float(max(u[on[0]], 0.0)) if ends[0] is None else float(ends[0]),
                                     float(min(u[on[-1]], length)) if ends[1] is None else float(ends[1]))))
    return out


def _junction_u(network: RoadNetwork, rid: str, other: str, s: int, m_near: float) -> float | None:
    """Lane coordinate on ``rid`` (direction ``s``) of its junction with road ``other`` nearest measure
    ``m_near``; None when the two roads share no junction (or ``other`` is ``rid``)."""
    if other == rid or other not in network.nodes_on:
        return None
    theirs = {n for _, n in network.nodes_on[other]}
    common = [m for m, n in network.nodes_on[rid] if n in theirs]
    if not common:
        return None
    m = min(common, key=lambda c: abs(c - m_near))
    return m if s > 0 else network.roads[rid].length - m


def _road_runs(road_id: np.ndarray, min_fixes: int) -> list[tuple[str, int, int, int | None, int | None]]:
    """Contiguous runs of fixes on one road: ``(road, first fix, last fix, last fix before, first fix after)``.

    Fixes matched to no road are skipped; runs of fewer than ``min_fixes`` fixes (a flicker at a
    junction) are dropped first, and the runs of one road they separated are joined again. ``before`` /
    ``after`` are the neighbouring runs' nearest fixes (None at the record's ends).
    """
    idx = [i for i, r in enumerate(road_id.tolist()) if r is not None]
    runs: list[list] = []
    for i in idx:
        if runs and runs[-1][0] == road_id[i]:
            runs[-1][2] = i
            runs[-1][3] += 1
        else:
            runs.append([road_id[i], i, i, 1])
    kept: list[list] = []
    for r in runs:
        if r[3] < min_fixes:
            continue
        if kept and kept[-1][0] == r[0]:
            kept[-1][2], kept[-1][3] = r[2], kept[-1][3] + r[3]
        else:
            kept.append(list(r))
    return [(str(r[0]), int(r[1]), int(r[2]), None if k == 0 else int(kept[k - 1][2]),
             None if k == len(kept) - 1 else int(kept[k + 1][1])) for k, r in enumerate(kept)]


def _split_turns(runs, matched, odo: np.ndarray, min_fixes: int, sigma_z: float) -> list:
    """Runs split where the drive turns back on the road (a U-turn): the measure's trend between fixes
    ``L`` apart (``L`` covering 8 GPS errors of odometer) changes sign and keeps it for ``min_fixes`` fixes."""
    out = []
    for rid, first, last, lo, hi in runs:
        idx = np.flatnonzero(matched.road_id[first:last + 1] == rid) + first
        m, o = matched.measure[idx], odo[idx]
        step = max(float(np.median(np.diff(o))) if idx.size > 1 else 1.0, 1e-3)
        lag = max(int(np.ceil(8.0 * sigma_z / step)), 1)
        if idx.size < 2 * lag + 2 * min_fixes:
            out.append((rid, first, last, lo, hi))
            continue
        trend = np.sign(m[2 * lag:] - m[:-2 * lag])            # at fix i + lag
        stretches: list[tuple[int, float]] = []               # (first fix, sign) of each lasting trend
        k = 0
        while k < trend.size:
            j = k
            while j < trend.size and trend[j] == trend[k]:
                j += 1
            if trend[k] != 0 and j - k >= min_fixes and (not stretches or stretches[-1][1] != trend[k]):
                stretches.append((k + lag, float(trend[k])))
            k = j
        # the turn: the extreme measure between two opposite trends
        bounds = [0]
        for (a, sa), (b, _) in zip(stretches, stretches[1:]):
            seg = m[a:min(b + lag + 1, m.size)]
            bounds.append(a + int(np.argmax(seg) if sa > 0 else np.argmin(seg)) + 1)
        bounds.append(idx.size)
        pieces = [(int(idx[p]), int(idx[q - 1])) for p, q in zip(bounds, bounds[1:]) if q > p]
        for n, (a, b) in enumerate(pieces):
            out.append((rid, a, b, lo if n == 0 else pieces[n - 1][1], hi if n == len(pieces) - 1 else pieces[n + 1][0]))
    return out


def lonlat_at(network: RoadNetwork, road_id: str, measure) -> tuple[np.ndarray, np.ndarray]:
    """WGS 84 position of measures along a road.

    Parameters
    ----------
    network : RoadNetwork
    road_id : str
    measure : array_like
        m from the road's start.

    Returns
    -------
    lon, lat : ndarray
    """
    line = network.roads[road_id].line
    pts = shapely.line_interpolate_point(line, np.atleast_1d(np.asarray(measure, float)))
    xy = shapely.get_coordinates(pts)
    return network.projection.to_lonlat(xy[:, 0], xy[:, 1])
