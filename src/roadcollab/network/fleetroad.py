"""The fleet's road: GPS drives through ``serve``/``vehicle`` onto one road of a network, drawn on the map.

Where the geometry lives
------------------------
``roadcollab enroll --network FILE --road-id ID`` copies the road network (the ``--network`` GeoJSON of
``roadcollab map``, :mod:`roadcollab.geo.network`) byte for byte into the fleet folder as
:data:`ROAD_FILE` and writes ``road_id`` and the file's SHA-256 into the fleet's plan
(:class:`~roadcollab.network.plan.RoadPlan`). The service and every vehicle read that one file and
check its hash (:meth:`FleetRoad.load`), so all parties project, match and cut with the same roads;
the plan, with the hash, is also in the service's store (an existing store refuses another plan).

The fleet's distance axis is then the road's measure (linear referencing from its first position,
m), in its forward direction:

* a vehicle matches its GPS fixes to the *whole* network (Newson & Krumm's HMM,
  :func:`roadcollab.geo.matching.road_passes`, as ``roadcollab map`` does, so that a drive on a road
  10 m beside the fleet's is matched to that road and refused, not folded onto the fleet's), takes its
  longest forward pass over the fleet's road, and keeps the samples on it, with positions
  ``m_0 + odometer`` (``m_0`` the least-squares offset of the matched fixes): :meth:`FleetRoad.place`.
  Its hello carries the road, the offset it applied and the fixes behind it (:func:`hello_fields`);
  the service refuses a hello on another road (or none);
* the road store (:class:`~roadcollab.network.roadsync.RoadSync`) cuts the fused profile into
  ``roadcollab map``'s segments (:func:`roadcollab.geo.segments.segment_bounds`, fixed in the road
  measure) where they are fully covered (:func:`road_iri`), and writes each segment's LineString
  (:func:`roadcollab.geo.segments.segment_lonlat`) and each anomaly's lon/lat
  (:func:`roadcollab.geo.matching.lonlat_at`): the very functions ``map`` writes with, on the same network.

Drives without GPS in a fleet without a road are unchanged (the plan has no road keys, the hello no
road fields): the distance-axis equality with ``roadcollab estimate`` holds as before.

The fleet's road is one road in its forward direction; a fleet on every road and both directions is
:mod:`roadcollab.network.fleetlanes` (``enroll --network FILE`` without ``--road-id``). Not done here: the network fleet does not align drives by cross-correlation, nor drop
each record's first and last 30 m as ``map`` does (the positions come from the GPS offset alone).
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, MessageError, ParameterError
from ..experiments.drives.distance_maps import estimate_offset
from ..geo.matching import lonlat_at, road_passes
from ..geo.network import RoadNetwork, read_network
from ..geo.segments import segment_bounds, segment_lonlat
from ..io.drives import Drive
from ..models.iri import IRISegments, iri
from ..experiments.drives.fleet_estimation import GUARD_ROAD_DEFAULT
from .engine import VehicleEngine
from .plan import RoadPlan

__all__ = ["ROAD_FILE", "MAX_OFFSET", "FleetRoad", "file_sha256", "check_road", "road_iri", "hello_fields",
           "check_hello", "align_to_waiting"]

#: The fleet folder's copy of the road network (written by ``roadcollab enroll --network``).
ROAD_FILE = "road-network.geojson"
#: Largest correction of a vehicle's GPS offset by cross-correlation, m (``roadcollab map``'s ``max_offset``).
MAX_OFFSET = 5.0


def file_sha256(path) -> str:
    """SHA-256 of a file's bytes, hex.

    Parameters
    ----------
    path : str or Path
    """
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def check_road(network: RoadNetwork, road_id: str, where: str) -> None:
    """Raise ParameterError naming ``where`` unless ``road_id`` is a road of ``network``.

    Parameters
    ----------
    network : RoadNetwork
    road_id : str
    where : str
        The option or file, for the message.
    """
    if road_id not in network.roads:
        known = list(network.roads)
        raise ParameterError(f"{where}: no road {road_id!r} in the network; expected one of "
                             f"{known[:10]}{' ...' if len(known) > 10 else ''}")


@dataclass(frozen=True, eq=False)
class FleetRoad:
    """The fleet's road in its network (module docstring).

    Attributes
    ----------
    network : RoadNetwork
        The fleet folder's network.
    road_id : str
        The fleet's road.
    """

    network: RoadNetwork
    road_id: str

    @classmethod
    def load(cls, folder, plan: RoadPlan) -> "FleetRoad | None":
        """The road of a fleet folder's plan; None for a fleet without a road (a fleet on every road:
        :func:`roadcollab.network.fleetlanes.load_road`).

        Parameters
        ----------
        folder : str or Path
            The fleet folder (``--fleet``).
        plan : RoadPlan
            Its plan.

        Raises
        ------
        FileFormatError
            The network file is missing, not a network, or not the one enrolled (another hash).
        """
        if not plan.road_id:
            return None
        path = Path(folder) / ROAD_FILE
        if not path.is_file():
            raise FileFormatError(f"{path}: missing; fleet {plan.fleet_id!r} surveys road {plan.road_id!r} of the "
                                  "network enrolled with it ('roadcollab enroll --network FILE --road-id ID')")
        if file_sha256(path) != plan.road_sha256:
            raise FileFormatError(f"{path}: not the network fleet {plan.fleet_id!r} was enrolled with (SHA-256 "
                                  f"differs from road_sha256 {plan.road_sha256[:12]}... of fleet.toml)")
        network = read_network(path)
        if plan.road_id == "*":
            raise ParameterError(f"{path}: fleet {plan.fleet_id!r} surveys every road of its network (load it with "
                                 "roadcollab.network.fleetlanes.load_road)")
        try:
            check_road(network, plan.road_id, str(path))
        except ParameterError as err:
            raise FileFormatError(str(err)) from None
        return cls(network, plan.road_id)

    @property
    def length(self) -> float:
        """The road's length, m."""
        return self.network.roads[self.road_id].length

    def segment_bounds(self, segment_length: float) -> list[tuple[float, float]]:
        """``roadcollab map``'s segments of the road, ``(from_m, to_m)`` in its measure.

        Parameters
        ----------
        segment_length : float
            m.
        """
        return segment_bounds(self.length, segment_length)

    def segment_lonlat(self, from_m: float, to_m: float) -> np.ndarray:
        """(K, 2) ``[lon, lat]`` of the road from ``from_m`` to ``to_m`` (``map``'s segment geometry).

        Parameters
        ----------
        from_m, to_m : float
            Measures, m.
        """
        return segment_lonlat(self.network, self.road_id, from_m, to_m)

    def lonlat(self, measure_m: float) -> tuple[float, float]:
        """``(lon, lat)`` of a measure along the road, WGS 84 degrees.

        Parameters
        ----------
        measure_m : float
            m.
        """
        lon, lat = lonlat_at(self.network, self.road_id, measure_m)
        return float(lon[0]), float(lat[0])

    def place(self, drive: Drive, *, sigma_z: float = 5.0) -> tuple[Drive, dict]:
        """The part of a GPS drive on the fleet's road, with positions in the road's measure.

        Parameters
        ----------
        drive : Drive
            With GPS fixes (``lat_deg, lon_deg`` columns).
        sigma_z : float
            GPS error standard deviation the matcher assumes, m (``map --gps-sigma``'s default 5).

        Returns
        -------
        Drive
            Its samples on the road (the longest forward pass), ``positions`` = road measure, m,
            ``gps`` None.
        dict
            The hello's road fields (:func:`hello_fields`).

        Raises
        ------
        ParameterError
            No GPS, or no pass of at least 50 m along the road in its forward direction (naming the
            roads the drive was matched to).
        """
        if drive.gps is None:
            raise ParameterError(f"{drive.csv_path}: expected lat_deg, lon_deg columns: fleet road {self.road_id!r} "
                                 "places every drive on it by its GPS fixes")
        passes = road_passes(drive, self.network, sigma_z=sigma_z)
        mine = [p for p in passes if p.road_id == self.road_id and p.direction > 0]
        if not mine:
            seen = sorted({f"{p.road_id}{p.direction:+d}" for p in passes})
            raise ParameterError(f"{drive.csv_path}: its GPS fixes do not follow road {self.road_id!r} forward for "
                                 f"50 m or more (matched: {', '.join(seen) or 'no road'}); the fleet surveys "
                                 f"{self.road_id}+1")
        p = max(mine, key=lambda q: q.u_range[1] - q.u_range[0])
        u = p.drive.positions
        on = np.flatnonzero((u >= p.u_range[0] - 1e-9) & (u <= p.u_range[1] + 1e-9))
        sl = slice(int(on[0]), int(on[-1]) + 1)
        pos = u[sl]
        t = drive.time[sl]
        speed = drive.speed if drive.constant_speed else float((pos[-1] - pos[0]) / (t[-1] - t[0]))
        placed = dataclasses.replace(drive, time=t, accel=drive.accel[sl], positions=pos, start_m=float(pos[0]),
                                     speed=speed, gps=None)
        return placed, hello_fields(self.road_id, float(u[0] - drive.positions[0]), p.n_fixes, p.offset_std)


def hello_fields(road_id: str, offset_m: float, n_fixes: int, offset_std_m: float) -> dict:
    """A placed vehicle's extra hello fields.

    Parameters
    ----------
    road_id : str
        The fleet's road.
    offset_m : float
        Road measure minus the log's own position (odometer or integrated speed), m: what the GPS fixes
        added to every position (``m_0`` of :func:`roadcollab.geo.matching.road_passes` less the log's start).
    n_fixes : int
        Fixes matched to the road.
    offset_std_m : float
        Standard error of the offset, m.
    """
    return {"road_id": road_id, "road_direction": 1, "road_offset_m": float(offset_m), "gps_fixes": int(n_fixes),
            "road_offset_std_m": float(offset_std_m)}


def check_hello(plan: RoadPlan, hello: dict) -> None:
    """Refuse a hello that is not on the fleet's road (a fleet with a road only).

    Parameters
    ----------
    plan : RoadPlan
    hello : dict

    Raises
    ------
    MessageError
    """
    if plan.road_id == "*":                              # every road of the network (network/fleetlanes.py)
        if hello.get("road_id") != "*":
            raise MessageError(f"hello: fleet {plan.fleet_id!r} surveys every road of its network; expected "
                               f"road_id '*' (a drive placed on its roads by its GPS), got {hello.get('road_id')!r}")
        return
    if plan.road_id and (hello.get("road_id") != plan.road_id or hello.get("road_direction") != 1):
        raise MessageError(f"hello: fleet {plan.fleet_id!r} surveys road {plan.road_id!r} forward; expected "
                           f"road_id {plan.road_id!r} and road_direction 1 (a drive placed on it by its GPS), got "
                           f"{hello.get('road_id')!r}")


def road_iri(position: np.ndarray, fused: np.ndarray, spacing: float, bounds: list[tuple[float, float]]
             ) -> IRISegments | None:
    """IRI of the fused profile on ``roadcollab map``'s segments that it covers whole.

    A segment ``[a, b]`` counts when every grid point in it is finite and its first and last grid
    points are within one step of ``a`` and ``b`` (as :func:`roadcollab.experiments.drives.road_survey.lane_survey`);
    its IRI per track is :func:`roadcollab.models.iri.iri` over those points (``map``'s too).

    Parameters
    ----------
    position : (n,) ndarray
        Grid, road measure, m.
    fused : (n, 2) ndarray
        Fused elevation, m, NaN where not covered.
    spacing : float
        Grid step, m.
    bounds : list of (float, float)
        The road's segments, m.

    Returns
    -------
    IRISegments or None
        None if no segment is covered whole.
    """
    rows = []
    for a, b in bounds:
        sel = (position >= a) & (position <= b)
        if np.count_nonzero(sel) < 2 or not np.isfinite(fused[sel]).all():
            continue
        x = position[sel]
        if x[0] - a > spacing or b - x[-1] > spacing:
            continue
        try:
            rows.append((a, b, iri(fused[sel, 0], spacing), iri(fused[sel, 1], spacing)))
        except ParameterError:               # shorter than the IRI's initialisation
            continue
    if not rows:
        return None
    start, end, left, right = (np.array(c, dtype=float) for c in zip(*rows))
    return IRISegments(start, end, left, right, tracks=2)


def align_to_waiting(engine: VehicleEngine, waiting: dict, *, index: int = 0, max_offset: float = MAX_OFFSET
                     ) -> VehicleEngine:
    """The engine on the drive shifted onto the waiting contributions (cross-correlation of the inversions).

    The GPS offset of each drive is known to a few tenths of a metre (``road_offset_std_m``); averaging
    inversions that far apart smooths the short wavelengths the IRI weighs. As ``roadcollab map``
    (``estimate_fleet(align=True)``) does, the vehicle estimates the lag ``L`` of its band-limited
    inversion against the previous vehicle's inversions waiting on its segments
    (:func:`~roadcollab.experiments.drives.distance_maps.estimate_offset`, within ``+-max_offset``, sub-sample
    by a parabola through the peak) and moves its positions by ``-L``. Unlike ``map``, which shifts the
    corrections to mean zero afterwards, the network cannot revise earlier vehicles: the first vehicle's
    GPS offset is the fleet's (its error, about ``road_offset_std_m``, is common to every position).

    Parameters
    ----------
    engine : VehicleEngine
        The vehicle's engine on its placed drive.
    waiting : dict
        ``{segment: Contribution}`` checked by the agent.
    index : int
        The engine's vehicle number (names its design).
    max_offset : float
        m.

    Returns
    -------
    VehicleEngine
        ``engine`` itself when nothing waits on 2 * ``max_offset`` or more of its stretch (or the lag is 0);
        else a new engine that contributes only on ``engine``'s segments (those its hello announced).
    """
    ref = np.full(engine.inversion.shape, np.nan)
    lo, hi = engine.i_first, engine.i_last + 1
    for c in waiting.values():
        a, b = max(c.i0, lo), min(c.i0 + c.n, hi)
        if b > a:
            ref[a - lo:b - lo] = c.inversion[a - c.i0:b - c.i0]
    overlap = np.isfinite(ref[:, 0]) & np.isfinite(engine.inversion[:, 0])
    if np.count_nonzero(overlap) * engine.plan.spacing < 2 * max_offset:
        return engine
    lag, _ = estimate_offset(ref, engine.inversion, engine.plan.spacing, max_offset)
    if lag == 0.0:
        return engine
    d = engine.drive
    moved = dataclasses.replace(d, positions=d.positions - lag, start_m=float(d.positions[0] - lag))
    return _Announced(moved, engine.plan, index=index, announced=engine.segments, guard=engine.guard)


class _Announced(VehicleEngine):
    """A realigned engine: it contributes only on the segments the hello announced (the service refuses
    others); a segment the shift moved it off is then "empty" for the agent."""

    def __init__(self, drive: Drive, plan: RoadPlan, *, index: int, announced: list[int],
                 guard: str | None = GUARD_ROAD_DEFAULT) -> None:
        super().__init__(drive, plan, index=index, guard=guard)
        self.announced = frozenset(announced)

    def contributions(self, waiting: dict | None = None) -> list:
        return [c for c in super().contributions(waiting) if c.segment in self.announced]
