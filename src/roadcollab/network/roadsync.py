"""The service's results in the road-condition store (:mod:`roadcollab.store`) while it serves.

:class:`RoadSync` is the observer :class:`~roadcollab.network.service.Service` calls when a segment's
fused sums change. It reads the service store back (:func:`~roadcollab.network.results.results_from_store`)
and computes the IRI per segment and the corroborated anomalies of the fused elevation with the very
functions ``roadcollab export`` uses (:func:`~roadcollab.experiments.drives.fleet_estimation.fused_iri`,
:func:`~roadcollab.experiments.drives.fleet_estimation.find_fleet_anomalies`), so the road store and
``export``'s ``iri.csv``/``anomalies.csv`` hold the same numbers.

What is written
---------------
- per IRI segment (``road_id`` = the fleet id, direction +1, ``from_m``/``to_m`` on the fleet's distance
  axis): IRI (m/km, in/mi), the 95 % interval ``fused ± 1.96 s / sqrt(V)`` of the IRI of each vehicle's own
  inversion on that segment alone (``s`` their standard deviation; NULL with fewer than two), the vehicles behind it
  (the most inversions covering a point of the segment) and the fused profile. A segment gets a new history
  row only when its IRI or vehicle count changed (a restarted service adds no copies).
- per anomaly of the fused elevation: a detection in the store's anomaly history when more vehicles are
  behind it than its stored votes (same kind within 2 m), with the new vehicles as votes, so the stored
  anomaly's votes are the vehicles behind the fused detection and its position and depth the vote-weighted
  means of the fused detections as the fleet grew (``RoadStore.record_anomaly``).

Geometry
--------
A fleet on a road (``enroll --network FILE --road-id ID``, :mod:`roadcollab.network.fleetroad`) has the
road's measure as its distance axis: ``road_id`` is that road, the segments are ``roadcollab map``'s
(fixed in the road's measure, only those the fused profile covers whole, :func:`~roadcollab.network.fleetroad.road_iri`),
each with its LineString (``[lon, lat]``, RFC 7946 order), and each anomaly has its lon/lat on the road.
A fleet on every road of its network (:mod:`roadcollab.network.fleetlanes`) writes each lane's segments
keyed ``(road_id, direction, from_m)``, cut from the lane's stretch of the fused profile, and each anomaly
on its lane (votes: the vehicles on that lane). A fleet without a road (drives without GPS) keeps its distance axis: segments from the start of each
covered stretch (``export``'s), empty geometry and anomalies at lon/lat 0.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import ParameterError
from ..experiments.drives.fleet_estimation import find_fleet_anomalies, fused_iri
from ..models.iri import iri_segments
from ..store import RoadStore
from .fleetlanes import NetworkLanes
from .fleetroad import FleetRoad, road_iri
from .results import results_from_store
from .store import ServiceStore

__all__ = ["RoadSync"]


class RoadSync:
    """Keeps a road store up to date with a service store.

    Parameters
    ----------
    roads : RoadStore
        The road-condition store (open; closed by the caller).
    service_store : ServiceStore
    segment_length : float
        IRI segment length, m (``export``'s default 100).
    source : str
        Written as each row's ``source``.
    min_interval_s : float
        At most one update per this many seconds while serving (0: after every change); :meth:`flush`
        writes what is pending.
    road : FleetRoad or NetworkLanes, optional
        The fleet's road (:meth:`FleetRoad.load` of the fleet folder): segments and anomalies get their
        geometry (module docstring); a fleet on every road (:class:`~roadcollab.network.fleetlanes.NetworkLanes`):
        each lane's segments keyed ``(road_id, direction, from_m)``; None: the fleet's distance axis, no
        geometry.
    """

    def __init__(self, roads: RoadStore, service_store: ServiceStore, *, segment_length: float = 100.0,
                 source: str = "roadcollab serve", min_interval_s: float = 0.0,
                 road: FleetRoad | NetworkLanes | None = None) -> None:
        self.roads, self.service_store = roads, service_store
        self.segment_length, self.source, self.min_interval_s = float(segment_length), source, float(min_interval_s)
        if road is not None and road.road_id != service_store.plan.road_id:
            raise ParameterError(f"road {road.road_id!r} is not the road of the store's plan "
                                 f"({service_store.plan.road_id!r})")
        self.road_id = service_store.plan.fleet_id if road is None else road.road_id
        self.net: NetworkLanes | None = road if isinstance(road, NetworkLanes) else None
        self.road: FleetRoad | None = road if isinstance(road, FleetRoad) else None
        self.lanes = self.net is not None
        self._last: dict[tuple, tuple[float, int]] = {
            (s.road_id, s.direction, s.from_m): (s.iri_m_per_km, s.n_vehicles) for s in roads.segments()
            if s.road_id == self.road_id or (self.net is not None and s.road_id in self.net.network.roads)}
        self._dirty, self._t = False, -np.inf
        self.written_segments = self.written_anomalies = 0

    def __call__(self, segment: int, store: ServiceStore) -> None:
        """The service's hook: a segment's fused sums changed.

        Parameters
        ----------
        segment : int
            The plan's segment index.
        store : ServiceStore
            The service's store (the one this object reads).
        """
        self._dirty = True
        if time.monotonic() - self._t >= self.min_interval_s:
            self.flush()

    def flush(self) -> tuple[int, int]:
        """Write the changed segments and the new anomalies; ``(segments, anomalies)`` written now."""
        if not self._dirty and self._t > -np.inf:
            return 0, 0
        self._dirty, self._t = False, time.monotonic()
        try:
            r = results_from_store(self.service_store)
        except ParameterError:                 # nothing applied yet
            return 0, 0
        view = r.fleet_view()
        if self.net is not None:
            n_seg = sum(self._segments(r, iri, lane) for lane, iri in self._lane_iri(r, self.net))
        else:
            if self.road is None:
                iri, _ = fused_iri(view, self.segment_length)
            else:
                iri = road_iri(r.position, r.fused, r.spacing, self.road.segment_bounds(self.segment_length))
            n_seg = 0 if iri is None else self._segments(r, iri)
        try:
            anomalies = find_fleet_anomalies(view)
        except ParameterError:                 # stretches too short for the detector: none yet
            anomalies = []
        n_an = self._anomalies(r, anomalies)
        self.written_segments += n_seg
        self.written_anomalies += n_an
        return n_seg, n_an

    def _lane_iri(self, r, lanes: NetworkLanes) -> list:
        """``((road_id, direction, origin), IRISegments on the axis)`` of every lane the fused profile covers:
        ``map``'s segments of the road, in the lane coordinate (reversed for direction -1)."""
        out = []
        for road, s in lanes.lanes:
            o, length = lanes.origin(road, s), lanes.length(road)
            bounds = [(a, b) if s > 0 else (length - b, length - a)
                      for a, b in lanes.segment_bounds(road, self.segment_length)]
            on = (r.position >= o - r.spacing) & (r.position <= o + length + r.spacing)
            if np.count_nonzero(np.isfinite(r.fused[on, 0])) < 2:
                continue
            iri = road_iri(r.position[on] - o, r.fused[on], r.spacing, sorted(bounds))
            if iri is not None:
                out.append(((road, s, o), iri))
        return out

    @staticmethod
    def _vehicle_iri(r, a: float, b: float) -> list[float]:
        """IRI of each vehicle's own inversion on ``[a, b]`` alone (the vehicles covering all of it)."""
        on = (r.position >= a - 1e-9) & (r.position <= b + 1e-9)
        out = []
        for j in range(len(r.vehicles)):
            inv = r.elevation["inversion"][j][on]
            if np.isfinite(inv).all():
                try:
                    out.append(float(iri_segments(r.position[on], inv, b - a).mean[0]))
                except (ParameterError, IndexError):   # shorter than the IRI's initialisation
                    continue
        return out

    def _segments(self, r, iri, lane=None) -> int:
        n = 0
        road, s, o = (self.road_id, 1, 0.0) if lane is None else lane
        for ua, ub, value in zip(iri.start.tolist(), iri.end.tolist(), iri.mean.tolist()):
            a, b = ua + o, ub + o                    # on the axis
            if self.net is None or s > 0:
                m_a, m_b = ua, ub
            else:                                     # the road's measure of a backward lane's stretch
                length = self.net.length(road)
                m_a, m_b = length - ub, length - ua
            key = (road, s, m_a)
            inside = (r.position >= a) & (r.position < b)
            k = int(r.coverage[inside].max()) if inside.any() else 0
            if self._last.get(key) is not None and np.isclose(self._last[key][0], value, rtol=1e-12, atol=0.0) \
                    and self._last[key][1] == k:
                continue
            own = self._vehicle_iri(r, a, b)
            lo = hi = None
            if len(own) >= 2:
                half = 1.96 * float(np.std(own, ddof=1)) / np.sqrt(len(own))
                lo, hi = max(value - half, 0.0), value + half
            if self.net is not None:
                geometry = self.net.segment_lonlat(road, m_a, m_b)
            elif self.road is not None:
                geometry = self.road.segment_lonlat(m_a, m_b)
            else:
                geometry = np.zeros((0, 2))
            self.roads.record_segment(road, s, m_a, m_b, geometry, value, iri_low=lo, iri_high=hi,
                                      n_vehicles=max(k, 1), profile=r.fused[inside], profile_spacing_m=r.spacing,
                                      source=self.source)
            self._last[key] = (value, k)
            n += 1
        return n

    def _anomalies(self, r, anomalies) -> int:
        # (road_id, direction, measure_m, kind, [votes]) of the stored anomalies on this fleet's road(s)
        net = self.net
        roads = set(net.network.roads) if net is not None else {self.road_id}
        stored: list[tuple[str, int, float, str, list[int]]] = [
            (a.road_id, a.direction, a.measure_m, a.kind, [a.votes]) for a in self.roads.anomalies() if a.road_id in roads]
        n = 0
        for row in anomalies:
            V = max(int(row.vehicle), 1)
            if net is not None:
                road, s, m = net.lane_at(row.position_m)
                if not 0.0 <= m <= net.length(road):
                    continue
                # the vehicles behind it are those on its lane (the view counts the whole fleet)
                V = max(min(V, int(r.coverage[int(np.argmin(np.abs(r.position - row.position_m)))])), 1)
            else:
                road, s, m = self.road_id, 1, row.position_m
            near = [a for a in stored if a[:2] == (road, s) and a[3] == row.kind and abs(a[2] - m) <= 2.0]
            new = V - (max(a[4][0] for a in near) if near else 0)
            if new <= 0:
                continue
            if net is not None:
                lon, lat = net.lonlat(road, m)
            elif self.road is not None:
                lon, lat = self.road.lonlat(m)
            else:
                lon, lat = 0.0, 0.0
            self.roads.record_anomaly(road, s, m, lon, lat, row.kind, row.side, row.depth_m, votes=new,
                                      source=self.source)
            if near:
                near[0][4][0] = V
            else:
                stored.append((road, s, m, row.kind, [V]))
            n += 1
        return n
