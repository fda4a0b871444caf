"""A fleet on a whole road network: every vehicle's GPS drive on the roads and directions it travels.

``roadcollab enroll --network FILE`` without ``--road-id`` enrolls a fleet on every road of the network
(plan ``road_id`` :data:`ALL_ROADS`, the file's SHA-256 as for one road, :mod:`roadcollab.network.fleetroad`).
The service's segments stay integers on one distance axis; the lanes are laid on it one after another:

Lane layout
-----------
The lanes are ``(road_id, direction)`` for every road in file order, direction +1 then -1. Lane ``k``'s
lane coordinate ``u`` (the road's measure for +1, ``length - measure`` for -1, as
:func:`roadcollab.geo.matching.road_passes` gives it) is the axis position ``k * stride + margin + u``,
with ``margin`` = :data:`LANE_MARGIN` and ``stride`` the longest road plus two margins, rounded up to
whole segments. Segment ``s`` of the plan is therefore on lane ``s // (stride / segment_length)``; the
road store's segments are ``roadcollab map``'s (:func:`roadcollab.geo.segments.segment_bounds`, fixed in
each road's measure) cut from the fused profile of each lane. Keys of the road store: ``road_id``,
``direction``, ``from_m`` (as ``map``'s).

A vehicle (:meth:`NetworkLanes.place`) matches its drive to the network (Newson & Krumm, as ``map``),
and for each pass takes its record from ``margin`` before to ``margin`` after the pass's stretch on the
road (``map`` inverts the whole record: the inversion's window edges reach about 48 m, inside the
margin), shifted onto the lane. One :class:`LaneEngine` per pass inverts it and contributes only on the
grid points of the road the pass covered; :class:`MultiLaneEngine` is the vehicle's engine over all of
them (one hello listing every segment of every lane). Two passes of one drive on the same lane (a loop)
are two stretches of the same vehicle: the second is dropped (the service takes one contribution per
vehicle and segment).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, ParameterError
from ..experiments.drives.distance_maps import estimate_offset
from ..experiments.drives.fleet_estimation import GUARD_ROAD_DEFAULT
from ..geo.matching import lonlat_at, road_passes
from ..geo.network import RoadNetwork, read_network
from ..geo.segments import segment_bounds, segment_lonlat
from ..io.drives import Drive
from .engine import VehicleEngine
from .fleetroad import MAX_OFFSET, ROAD_FILE, FleetRoad, align_to_waiting, file_sha256
from .plan import RoadPlan

__all__ = ["ALL_ROADS", "LANE_MARGIN", "NetworkLanes", "LaneEngine", "MultiLaneEngine", "align_lanes",
           "placed_engine", "load_road"]

#: ``road_id`` of a plan whose fleet surveys every road of its network.
ALL_ROADS = "*"
#: Record kept before and after a pass's stretch on its road, m (the inversion's edges stay off the road).
LANE_MARGIN = 100.0


@dataclass(frozen=True, eq=False)
class NetworkLanes:
    """Every lane of a network on the fleet's distance axis (module docstring).

    Attributes
    ----------
    network : RoadNetwork
    segment_length : float
        The plan's segment length, m.
    """

    network: RoadNetwork
    segment_length: float

    road_id = ALL_ROADS

    @property
    def lanes(self) -> list[tuple[str, int]]:
        """``(road_id, direction)`` in axis order."""
        return [(r, s) for r in self.network.roads for s in (1, -1)]

    @property
    def stride(self) -> float:
        """Axis length of one lane, m (whole segments)."""
        longest = max(r.length for r in self.network.roads.values())
        return math.ceil((longest + 2 * LANE_MARGIN) / self.segment_length) * self.segment_length

    def origin(self, road_id: str, direction: int) -> float:
        """Axis position of lane coordinate 0 of a lane, m.

        Parameters
        ----------
        road_id : str
        direction : int
        """
        return self.lanes.index((road_id, direction)) * self.stride + LANE_MARGIN

    def length(self, road_id: str) -> float:
        """A road's length, m.

        Parameters
        ----------
        road_id : str
        """
        return self.network.roads[road_id].length

    def segment_bounds(self, road_id: str, segment_length: float) -> list[tuple[float, float]]:
        """``roadcollab map``'s segments of a road, ``(from_m, to_m)`` in its measure.

        Parameters
        ----------
        road_id : str
        segment_length : float
            m.
        """
        return segment_bounds(self.length(road_id), segment_length)

    def segment_lonlat(self, road_id: str, from_m: float, to_m: float) -> np.ndarray:
        """(K, 2) ``[lon, lat]`` of a road from ``from_m`` to ``to_m``.

        Parameters
        ----------
        road_id : str
        from_m, to_m : float
            Measures, m.
        """
        return segment_lonlat(self.network, road_id, from_m, to_m)

    def lonlat(self, road_id: str, measure_m: float) -> tuple[float, float]:
        """``(lon, lat)`` of a measure along a road.

        Parameters
        ----------
        road_id : str
        measure_m : float
        """
        lon, lat = lonlat_at(self.network, road_id, measure_m)
        return float(lon[0]), float(lat[0])

    def lane_at(self, x: float) -> tuple[str, int, float]:
        """``(road_id, direction, road measure)`` of an axis position.

        Parameters
        ----------
        x : float
            m.
        """
        road, s = self.lanes[min(max(int(x // self.stride), 0), len(self.lanes) - 1)]
        u = x - self.origin(road, s)
        return road, s, (u if s > 0 else self.length(road) - u)

    def place(self, drive: Drive, *, sigma_z: float = 5.0) -> list[tuple[tuple[str, int], Drive, tuple]]:
        """The drive's passes on the axis (module docstring).

        Parameters
        ----------
        drive : Drive
            With GPS fixes.
        sigma_z : float
            GPS error the matcher assumes, m.

        Returns
        -------
        list of ((road_id, direction), Drive, (lo, hi))
            Per lane it passed: the record from ``LANE_MARGIN`` before to after its stretch, positions on the
            axis; ``lo, hi`` the axis positions of the stretch on the road.

        Raises
        ------
        ParameterError
            No GPS, or no pass of 50 m on any road.
        """
        if drive.gps is None:
            raise ParameterError(f"{drive.csv_path}: expected lat_deg, lon_deg columns: the fleet surveys the "
                                 "roads of its network and places every drive on them by its GPS fixes")
        out, seen = [], set()
        for p in road_passes(drive, self.network, sigma_z=sigma_z):
            lane = (p.road_id, p.direction)
            if lane in seen:
                continue
            seen.add(lane)
            o = self.origin(*lane)
            u = p.drive.positions
            keep = np.flatnonzero((u >= p.u_range[0] - LANE_MARGIN) & (u <= p.u_range[1] + LANE_MARGIN))
            sl = slice(int(keep[0]), int(keep[-1]) + 1)
            pos, t = u[sl] + o, drive.time[sl]
            speed = drive.speed if drive.constant_speed else float((pos[-1] - pos[0]) / (t[-1] - t[0]))
            d = dataclasses.replace(drive, time=t, accel=drive.accel[sl], positions=pos, start_m=float(pos[0]),
                                    speed=speed, gps=None)
            out.append((lane, d, (o + p.u_range[0], o + p.u_range[1])))
        if not out:
            raise ParameterError(f"{drive.csv_path}: its GPS fixes follow no road of the fleet's network for 50 m "
                                 "or more")
        return out

    def hello_fields(self, placed) -> dict:
        """A placed vehicle's extra hello fields: the network and its lanes.

        Parameters
        ----------
        placed : list
            :meth:`place`'s result.
        """
        return {"road_id": ALL_ROADS, "road_direction": 0,
                "lanes": [f"{r}{s:+d}" for (r, s), _d, _k in placed]}


class LaneEngine(VehicleEngine):
    """A vehicle's engine on one lane: the inversion of its record around the pass, contributing only on
    the axis stretch ``keep`` (the road it covered; :meth:`NetworkLanes.place`).

    Parameters
    ----------
    drive : Drive
        Positions on the axis.
    plan : RoadPlan
    keep : (float, float)
        Axis positions of the pass's stretch on the road, m.
    index : int
        Vehicle number.
    announced : iterable of int, optional
        Contribute only on these segments (a realigned engine: the ones its hello announced).
    guard : {"class", "own"} or None
        The receiver guard's road prior (:class:`~roadcollab.network.engine.VehicleEngine`).
    """

    def __init__(self, drive: Drive, plan: RoadPlan, keep: tuple, *, index: int = 0, announced=None,
                 guard: str | None = GUARD_ROAD_DEFAULT) -> None:
        super().__init__(drive, plan, index=index, guard=guard)
        self.keep = (float(keep[0]), float(keep[1]))
        off = (self.x < self.keep[0]) | (self.x > self.keep[1])
        self.single[off] = np.nan
        self.inversion[off] = np.nan
        self.announced = None if announced is None else frozenset(announced)

    def contributions(self, waiting: dict | None = None) -> list:
        out = super().contributions(waiting)
        return out if self.announced is None else [c for c in out if c.segment in self.announced]


class MultiLaneEngine:
    """A vehicle's engine over every lane it passed: the :class:`LaneEngine` of each, one set of segments.

    Parameters
    ----------
    engines : list of LaneEngine
        Non-empty, on disjoint lanes.
    """

    def __init__(self, engines: list) -> None:
        if not engines:
            raise ParameterError("a vehicle on the network needs at least one pass")
        self.engines = list(engines)
        self.plan = engines[0].plan
        self.drive = engines[0].drive

    @property
    def segments(self) -> list[int]:
        """Every lane's segments, in order."""
        return sorted(s for e in self.engines for s in e.segments)

    def contributions(self, waiting: dict | None = None) -> list:
        """Every lane's contributions with the waiting messages on its segments.

        Parameters
        ----------
        waiting : dict, optional
            ``{segment: Contribution}``.
        """
        waiting = waiting or {}
        out = []
        for e in self.engines:
            mine = set(e.segments)
            out += e.contributions({s: c for s, c in waiting.items() if s in mine})
        return sorted(out, key=lambda c: c.segment)


def align_lanes(engine: MultiLaneEngine, waiting: dict, *, index: int = 0) -> MultiLaneEngine:
    """Each lane's engine aligned to the waiting contributions on its segments
    (:func:`roadcollab.network.fleetroad.align_to_waiting`'s cross-correlation, lane by lane: each pass has
    its own GPS offset).

    Parameters
    ----------
    engine : MultiLaneEngine
    waiting : dict
        ``{segment: Contribution}`` checked by the agent.
    index : int
        Vehicle number.
    """
    out = []
    for e in engine.engines:
        mine = set(e.segments)
        ref = np.full(e.inversion.shape, np.nan)
        lo, hi = e.i_first, e.i_last + 1
        for s, c in waiting.items():
            if s not in mine:
                continue
            a, b = max(c.i0, lo), min(c.i0 + c.n, hi)
            if b > a:
                ref[a - lo:b - lo] = c.inversion[a - c.i0:b - c.i0]
        overlap = np.isfinite(ref[:, 0]) & np.isfinite(e.inversion[:, 0])
        if np.count_nonzero(overlap) * e.plan.spacing < 2 * MAX_OFFSET:
            out.append(e)
            continue
        lag, _ = estimate_offset(ref, e.inversion, e.plan.spacing, MAX_OFFSET)
        if lag == 0.0:
            out.append(e)
            continue
        d = e.drive
        moved = dataclasses.replace(d, positions=d.positions - lag, start_m=float(d.positions[0] - lag))
        out.append(LaneEngine(moved, e.plan, (e.keep[0] - lag, e.keep[1] - lag), index=index, announced=e.segments,
                              guard=e.guard))
    return MultiLaneEngine(out)


def placed_engine(drive: Drive, plan: RoadPlan, road, index: int, guard: str | None = GUARD_ROAD_DEFAULT) -> tuple:
    """A vehicle's engine, hello fields and realignment for the fleet's kind of road.

    Parameters
    ----------
    drive : Drive
        The vehicle's drive (with GPS for a fleet on a road or a network).
    plan : RoadPlan
    road : FleetRoad, NetworkLanes or None
        :meth:`~roadcollab.network.fleetroad.FleetRoad.load` of the fleet folder.
    index : int
        Vehicle number.
    guard : {"class", "own"} or None
        The receiver guard's road prior (None: unguarded, ``vehicle --unguarded-receive``).

    Returns
    -------
    (engine, hello_extra, realign)
        On the fleet's road (:meth:`~roadcollab.network.fleetroad.FleetRoad.place`,
        :func:`~roadcollab.network.fleetroad.align_to_waiting`), on every lane of its network
        (:class:`MultiLaneEngine`, :func:`align_lanes`), or on the drive's own axis (``None, None``).
    """
    if road is None:
        return VehicleEngine(drive, plan, index=index, guard=guard), None, None
    if isinstance(road, NetworkLanes):
        placed = road.place(drive)
        engine = MultiLaneEngine([LaneEngine(pd, plan, keep, index=index, guard=guard) for _lane, pd, keep in placed])
        return engine, road.hello_fields(placed), functools.partial(align_lanes, index=index)
    d, extra = road.place(drive)
    return VehicleEngine(d, plan, index=index, guard=guard), extra, functools.partial(align_to_waiting, index=index)


def load_road(folder, plan: RoadPlan) -> "FleetRoad | NetworkLanes | None":
    """The road(s) of a fleet folder's plan: None without a road, a :class:`FleetRoad` on one road, a
    :class:`NetworkLanes` on every road (``road_id`` :data:`ALL_ROADS`).

    Parameters
    ----------
    folder : str or Path
        The fleet folder.
    plan : RoadPlan
        Its plan.

    Raises
    ------
    FileFormatError
        The network file is missing, not a network, or not the one enrolled.
    """
    if plan.road_id != ALL_ROADS:
        return FleetRoad.load(folder, plan)
    path = Path(folder) / ROAD_FILE
    if not path.is_file():
        raise FileFormatError(f"{path}: missing; fleet {plan.fleet_id!r} surveys every road of the network enrolled "
                              "with it ('roadcollab enroll --network FILE')")
    if file_sha256(path) != plan.road_sha256:
        raise FileFormatError(f"{path}: not the network fleet {plan.fleet_id!r} was enrolled with (SHA-256 differs "
                              f"from road_sha256 {plan.road_sha256[:12]}... of fleet.toml)")
    return NetworkLanes(read_network(path), plan.segment_length)
