"""A simulated city: a small road network, profiles with known potholes, GPS drives at mixed speeds.

The network (:func:`city_network`, local metres east/north of ``CITY_ORIGIN``):

* ``main`` from (0, 0) to (600, 0) and ``cross`` from (600, 0) to (600, -500): one route that turns
  at the junction (600, 0);
* ``side`` from (300, 0) to (300, -400): a T-junction onto the middle of ``main`` (its measure 300);
* ``service``, parallel to ``main`` 10 m north of it, from (0, 10) to (600, 10), not connected to it
  (its end is 10 m from the junction, beyond the 1 m junction tolerance).

Every lane (a road and a direction of travel: the two directions are different wheel tracks) has its
own two-track profile (ISO 8608 class B random walk, :func:`~roadcollab.models.road.generate_road`)
with its potholes (:data:`CITY_POTHOLES`); a route's profile is its lanes' pieces joined end to end
(each piece shifted to continue the elevation), so two routes over the same lane see the same road.
Drives (:func:`simulate_city`, :data:`CITY_ROUTES`): ``main`` then ``cross`` at 12, 15, 18, 13-17
(varying) and 14 m/s; ``service`` at 15 and 16 m/s; ``main`` to the T-junction then ``side``
(turning right) at 13, 16 and 14.5 m/s; and back: ``side`` against its measure then ``main`` against
its measure from the T-junction to its start (turning left) at 14 and 16.5 m/s. Each runs from 5 m
after its route's start to 5 m before its end, 100 Hz accelerometers with noise 0.05 m/s^2, a
``speed_mps`` column, and 5 Hz GPS fixes with independent N(0, 3 m) errors east and north.
Vehicles: :func:`~roadcollab.models.vehicle.sample_fleet` with the default spread; a drive is simulated
with its vehicle's true parameters and its parameters file carries the vehicle's estimate of them
(10 % error per parameter), the source of each vehicle's IRI bias (docs/map.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...geo.network import RoadNetwork, network_from_lonlat
from ...geo.projection import LocalProjection
from ...io.drive_params import write_drive_params
from ...io.drives import Drive
from ...io.gps import write_gps_drive_csv
from ...models.anomaly import Anomaly
from ...models.profile import RoadProfile
from ...models.road import RoadSpec, generate_road, moving_average
from ...models.vehicle import FleetSpec, sample_fleet
from .mixed_fleet import simulate_drive

__all__ = ["CITY_ORIGIN", "CITY_ROADS", "CITY_POTHOLES", "CITY_ROUTES", "ROUTE_SPEEDS", "SERVICE_SPEEDS", "CityTruth",
           "city_network", "city_profiles", "default_potholes", "simulate_city", "network_geojson", "write_city"]

CITY_ORIGIN = (48.137, 11.575)   # lat, lon (degrees)
#: Road positions in metres east/north of the origin.
CITY_ROADS = {"main": [(0.0, 0.0), (300.0, 0.0), (600.0, 0.0)], "cross": [(600.0, 0.0), (600.0, -500.0)],
              "service": [(0.0, 10.0), (600.0, 10.0)], "side": [(300.0, 0.0), (300.0, -400.0)]}
#: (road, measure of the centre m, track, depth m, length m[, direction]) of every pothole; the track is
#: the vehicle's left or right in its direction of travel; direction +1 (the default) or -1 (the lane
#: against the road's measure).
CITY_POTHOLES = (("main", 150.0, "both", 0.05, 0.6), ("main", 420.0, "left", 0.04, 0.5),
                 ("cross", 230.0, "right", 0.06, 0.8), ("cross", 380.0, "both", 0.035, 0.5),
                 ("service", 330.0, "both", 0.05, 0.6), ("side", 200.0, "left", 0.045, 0.6),
                 ("side", 120.0, "right", 0.05, 0.6, -1), ("main", 90.0, "both", 0.04, 0.6, -1))
ROUTE_SPEEDS = (12.0, 15.0, 18.0, (13.0, 17.0), 14.0)
SERVICE_SPEEDS = (15.0, 16.0)
TURN_SPEEDS = (13.0, 16.0, 14.5)
BACK_SPEEDS = (14.0, 16.5)
#: Routes of the city's drives: pieces ``(road, from_m, to_m)`` travelled from ``from_m`` to ``to_m``
#: (against the road's measure when ``from_m > to_m``), and the speeds they are driven at.
CITY_ROUTES = (((("main", 0.0, 600.0), ("cross", 0.0, 500.0)), ROUTE_SPEEDS),
               (((("service", 0.0, 600.0),)), SERVICE_SPEEDS),
               ((("main", 0.0, 300.0), ("side", 0.0, 400.0)), TURN_SPEEDS),
               ((("side", 400.0, 0.0), ("main", 300.0, 0.0)), BACK_SPEEDS))
#: With ``shared_vehicles``: drive index (0-based) -> the earlier drive whose vehicle drives it too. The
#: service-road drives (6-7) by the vehicles of drives 1-2, the drives back (11-12) by those of 8-9: eight
#: vehicles, each linked to the others through the lanes they share (for the per-vehicle calibration).
SHARED_VEHICLES = {5: 0, 6: 1, 10: 7, 11: 8}
SAMPLE_RATE = 100.0
GPS_RATE = 5.0
GPS_SIGMA = 3.0
_MARGIN = 20.0     # m of profile past a route's end


@dataclass(frozen=True, eq=False)
class CityTruth:
    """What the simulation knows.

    Attributes
    ----------
    network : RoadNetwork
    lanes : dict
        ``{(road_id, direction): RoadProfile}``: each lane's true profile in its lane coordinate ``u``
        (the road's measure for direction +1, ``length - measure`` for -1), 0 to the road's length plus
        20 m, with its potholes.
    profiles : dict
        ``{route: RoadProfile}`` of every route (the road ids joined by ``+``), distance = route distance.
    potholes : tuple
        ``(road_id, measure_m, side, depth_m, length_m[, direction])`` of every pothole.
    drives : list of Drive
        As simulated (positions = true route distance), with GPS fixes.
    roads_driven : list of tuple
        The roads each drive travels.
    routes : list of tuple
        Each drive's route: pieces ``(road_id, from_m, to_m)`` (:data:`CITY_ROUTES`).
    vehicles : tuple of Vehicle
        Each drive's vehicle: the true parameters it was simulated with and the estimated ones its
        parameters file carries (``FleetSpec().estimate_uncertainty``, 10 % per parameter).
    """

    network: RoadNetwork
    lanes: dict
    profiles: dict
    potholes: tuple
    drives: list
    roads_driven: list
    routes: list
    vehicles: tuple = ()

    def road_profile(self, road_id: str, direction: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Lane coordinate (m) and (n, 2) elevation (m) of one lane's true profile, on the road only.

        Parameters
        ----------
        road_id : str
        direction : int
            +1 (along the road's measure, the default) or -1; for -1 the coordinate is
            ``length - measure`` and the tracks are the left/right of a vehicle driving that way.

        Returns
        -------
        u, elevation : ndarray
        """
        p = self.lanes[(road_id, direction)]
        keep = p.distance <= self.network.roads[road_id].length + 1e-9
        return np.asarray(p.distance[keep]), np.asarray(p.elevation[keep])

    def potholes_lonlat(self) -> list[dict]:
        """Every pothole: road, direction, measure, lon, lat, depth (m).

        Returns
        -------
        list of dict
        """
        out = []
        for road, m, side, depth, _length, *rest in self.potholes:
            line = self.network.roads[road].line
            pt = line.interpolate(m)
            lon, lat = self.network.projection.to_lonlat(pt.x, pt.y)
            out.append({"road_id": road, "direction": int(rest[0]) if rest else 1, "measure_m": m, "lon": float(lon),
                        "lat": float(lat), "depth_m": depth, "side": side})
        return out


def city_network() -> RoadNetwork:
    """The city's roads (module docstring) as a RoadNetwork.

    Returns
    -------
    RoadNetwork
    """
    proj = LocalProjection(*CITY_ORIGIN)
    roads = {}
    for rid, pts in CITY_ROADS.items():
        xy = np.array(pts)
        lon, lat = proj.to_lonlat(xy[:, 0], xy[:, 1])
        roads[rid] = np.column_stack([lon, lat])
    return network_from_lonlat(roads)


def _with_potholes(profile: RoadProfile, potholes: list[tuple[float, str, float, float]]) -> RoadProfile:
    d = np.asarray(profile.distance)
    spacing = float(d[1] - d[0])
    bumps = np.zeros_like(profile.elevation)
    truth = []
    for centre, side, depth, length in potholes:
        a = Anomaly(centre - 0.5 * length, side, "pothole", depth, length)
        for t in a.tracks:
            bumps[:, t] += a.elevation(d)
        truth.append(a)
    return RoadProfile(d, profile.elevation + moving_average(bumps, spacing, 0.25), tuple(truth), profile.source)


def _pieces(route) -> list[tuple[str, int, float, float]]:
    """``(road, direction, u_from, u_to)`` of every piece of a route (lane coordinates, increasing)."""
    return [(r, 1 if b >= a else -1, a, b) for r, a, b in route]


def city_profiles(network: RoadNetwork, routes, potholes, *, rng=None) -> tuple[dict, dict]:
    """The true profiles of every lane and route (module docstring).

    Parameters
    ----------
    network : RoadNetwork
    routes : sequence of tuple
        Each a sequence of pieces ``(road_id, from_m, to_m)`` driven one after the other.
    potholes : sequence of tuple
        ``(road_id, measure_m, side, depth_m, length_m[, direction])``.
    rng : numpy.random.Generator | int | None

    Returns
    -------
    lanes : dict
        ``{(road_id, direction): RoadProfile}`` in the lane coordinate, ISO class B, 20 m longer than the
        road, with its potholes (generated in the order the routes first drive them).
    profiles : dict
        ``{route name: RoadProfile}``: the lanes' pieces joined, each shifted to continue the elevation,
        20 m past the route's end.
    """
    rng = np.random.default_rng(rng)
    lanes: dict = {}
    for route in routes:
        for r, s, _a, _b in _pieces(route):
            if (r, s) in lanes:
                continue
            length = network.roads[r].length
            base = generate_road(RoadSpec(length=length + _MARGIN, iso_class="B", anomaly_density=0.0), rng=rng)
            on = [(m if s > 0 else length - m, side, depth, plen) for r2, m, side, depth, plen, *d in potholes
                  if r2 == r and (d[0] if d else 1) == s]
            lanes[(r, s)] = _with_potholes(base, on)
    profiles = {}
    for route in routes:
        xs: list[np.ndarray] = []
        hs: list[np.ndarray] = []
        start = 0.0
        pieces = _pieces(route)
        for k, (r, s, a, b) in enumerate(pieces):
            length = network.roads[r].length
            u0, u1 = (a, b) if s > 0 else (length - a, length - b)
            lane = lanes[(r, s)]
            d = np.asarray(lane.distance)
            last = k == len(pieces) - 1
            sel = (d >= u0 - 1e-9) & ((d <= u1 + _MARGIN + 1e-9) if last else (d < u1 - 1e-9))
            h = np.asarray(lane.elevation)[sel]
            if hs:
                h = h - h[0] + hs[-1][-1]
            xs.append(start + d[sel] - d[sel][0])
            hs.append(h)
            start += u1 - u0
        x = np.concatenate(xs)
        spacing = float(np.asarray(lanes[pieces[0][:2]].distance)[1])
        x = spacing * np.arange(x.size)          # one grid: the pieces are whole numbers of steps
        profiles["+".join(r for r, *_ in route)] = RoadProfile(x, np.concatenate(hs), (), "city route")
    return lanes, profiles


def default_potholes(network: RoadNetwork) -> tuple:
    """Potholes for a user's network: 5 cm (both tracks) at 30 % and 4 cm (left) at 70 % of every road.

    Parameters
    ----------
    network : RoadNetwork

    Returns
    -------
    tuple
        ``(road_id, measure_m, side, depth_m, length_m)``.
    """
    return tuple(p for rid, r in network.roads.items()
                 for p in ((rid, 0.3 * r.length, "both", 0.05, 0.6), (rid, 0.7 * r.length, "left", 0.04, 0.5)))


def _gps(drive: Drive, network: RoadNetwork, route: tuple, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """lat, lon (NaN between fixes) at GPS_RATE with N(0, GPS_SIGMA) errors east and north."""
    step = int(round(SAMPLE_RATE / GPS_RATE))
    k = np.arange(0, drive.n_samples, step)
    ends = np.cumsum([0.0] + [abs(b - a) for _r, a, b in route])
    xy = np.empty((k.size, 2))
    for i, p in enumerate(drive.positions[k]):
        j = min(int(np.searchsorted(ends, p, side="right")) - 1, len(route) - 1)
        r, a, b = route[j]
        m = a + np.sign(b - a) * float(p - ends[j])
        pt = network.roads[r].line.interpolate(m)
        xy[i] = (pt.x, pt.y)
    xy += rng.normal(0.0, GPS_SIGMA, xy.shape)
    lon, lat = network.projection.to_lonlat(xy[:, 0], xy[:, 1])
    full_lat, full_lon = np.full(drive.n_samples, np.nan), np.full(drive.n_samples, np.nan)
    full_lat[k], full_lon[k] = lat, lon
    return full_lat, full_lon


def simulate_city(*, seed: int = 0, network: RoadNetwork | None = None, speeds=None, vehicles: int = 3,
                  shared_vehicles: bool = False) -> tuple[CityTruth, list[tuple[np.ndarray, np.ndarray]]]:
    """The simulated drives with their GPS (module docstring).

    Parameters
    ----------
    seed : int
        Seeds the profiles, the fleet, the sensor noise and the GPS errors (independent children).
    network : RoadNetwork, optional
        A user's network instead of the built-in city: every road is driven on its own, forward, by
        ``vehicles`` vehicles at ``speeds`` (cycled), with :func:`default_potholes`.
    speeds : sequence of float, optional
        m/s, for a user's network (default 12, 15, 18).
    vehicles : int
        Drives per road of a user's network.
    shared_vehicles : bool
        Built-in city only: vehicles make several trips (:data:`SHARED_VEHICLES`); default: every drive its
        own vehicle.

    Returns
    -------
    CityTruth
    list of (lat, lon)
        Per drive, (N,) arrays with NaN between fixes.
    """
    builtin = network is None
    if network is None:
        network, potholes = city_network(), CITY_POTHOLES
        plan = [(route, v) for route, vs in CITY_ROUTES for v in vs]
    else:
        speeds = (12.0, 15.0, 18.0) if speeds is None else tuple(speeds)
        potholes = default_potholes(network)
        plan = [(((rid, 0.0, r.length),), speeds[j % len(speeds)]) for rid, r in network.roads.items()
                for j in range(vehicles)]
    ss = np.random.SeedSequence(seed)
    road_rng, fleet_rng, *drive_seeds = ss.spawn(2 + len(plan))
    routes = list(dict.fromkeys(route for route, _ in plan))
    lanes, profiles = city_profiles(network, routes, potholes, rng=np.random.default_rng(road_rng))
    fleet = sample_fleet(len(plan), FleetSpec(), rng=np.random.default_rng(fleet_rng))
    if shared_vehicles and builtin:
        fleet = [fleet[SHARED_VEHICLES.get(j, j)] for j in range(len(fleet))]
    drives, gps = [], []
    for j, ((route, speed), child) in enumerate(zip(plan, drive_seeds)):
        rng = np.random.default_rng(child)
        road = profiles["+".join(r for r, *_ in route)]
        end = sum(abs(b - a) for _r, a, b in route)
        d = simulate_drive(road, fleet[j], speed, start=0.0, end_margin=float(road.distance[-1]) - end + 5.0,
                           sample_rate=SAMPLE_RATE, rng=rng)
        drives.append(d)
        gps.append(_gps(d, network, route, rng))
    truth = CityTruth(network=network, lanes=lanes, profiles=profiles, potholes=tuple(potholes), drives=drives,
                      roads_driven=[tuple(r for r, *_ in route) for route, _ in plan],
                      routes=[route for route, _ in plan], vehicles=tuple(fleet))
    return truth, gps


def network_geojson(network: RoadNetwork) -> dict:
    """The network as an RFC 7946 FeatureCollection (the ``--network`` format).

    Parameters
    ----------
    network : RoadNetwork

    Returns
    -------
    dict
    """
    return {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"road_id": rid},
         "geometry": {"type": "LineString", "coordinates": [[float(a), float(b)] for a, b in r.lonlat]}}
        for rid, r in network.roads.items()]}


def write_city(out, *, seed: int = 0, network: RoadNetwork | None = None, speeds=None, vehicles: int = 3,
               shared_vehicles: bool = False) -> dict:
    """Write the city: ``network.geojson``, ``drive<j>.csv`` + ``.toml`` and ``truth.json`` into ``out``.

    Parameters
    ----------
    out : Path
        An existing directory (the command stages it).
    seed, network, speeds, vehicles, shared_vehicles
        See :func:`simulate_city`; with ``shared_vehicles`` every parameters file names its vehicle
        (``vehicle_id = "veh<k>"``, k the first drive it made).

    Returns
    -------
    dict
        ``{"network": path, "drives": [paths], "truth": path}``.
    """
    out = Path(out)
    truth, gps = simulate_city(seed=seed, network=network, speeds=speeds, vehicles=vehicles,
                               shared_vehicles=shared_vehicles)
    vid_of = (lambda j: f"veh{SHARED_VEHICLES.get(j - 1, j - 1) + 1}") if shared_vehicles and network is None \
        else None
    net = out / "network.geojson"
    net.write_text(json.dumps(network_geojson(truth.network), indent=1))
    paths = []
    for j, (d, (lat, lon)) in enumerate(zip(truth.drives, gps), start=1):
        constant = d.speed_source == "parameters"
        p = write_gps_drive_csv(out / f"drive{j}.csv", d.time, d.accel, lat, lon,
                                column=None if constant else "speed_mps", values=None if constant else d.speeds())
        write_drive_params(out / f"drive{j}.toml", speed=d.speed if constant else None, params=d.params,
                           vehicle_id=vid_of(j) if vid_of else None)
        paths.append(p)
    doc = {"seed": seed, **({"shared_vehicles": True} if vid_of else {}), "gps_sigma_m": GPS_SIGMA, "gps_rate_hz": GPS_RATE, "sample_rate_hz": SAMPLE_RATE,
           "roads_driven": [list(r) for r in truth.roads_driven],
           "routes": [[list(p) for p in r] for r in truth.routes], "potholes": truth.potholes_lonlat()}
    (out / "truth.json").write_text(json.dumps(doc, indent=1))
    return {"network": net, "drives": paths, "truth": out / "truth.json"}
