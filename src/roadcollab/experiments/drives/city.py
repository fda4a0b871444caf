"""A simulated city: a small road network, profiles with known potholes, GPS drives at mixed speeds.

The network (:func:`city_network`, local metres east/north of ``CITY_ORIGIN``):

* ``main`` from (0, 0) to (600, 0) and ``cross`` from (600, 0) to (600, -500): one route that turns
  at the junction (600, 0);
* ``service``, parallel to ``main`` 10 m north of it, from (0, 10) to (600, 10), not connected to it
  (its end is 10 m from the junction, beyond the 1 m junction tolerance).

The route ``main`` + ``cross`` is one continuous two-track profile (ISO 8608 class B random walk,
:func:`~roadcollab.models.road.generate_road`) with :data:`CITY_POTHOLES` added; ``service`` has its
own. Drives (:func:`simulate_city`) run the route at 12, 15, 18, 13-17 (varying) and 14 m/s and
``service`` at 15 and 16 m/s, from 5 m before the start to 5 m before the end, 100 Hz accelerometers
with noise 0.05 m/s^2, a ``speed_mps`` column, and 5 Hz GPS fixes with independent N(0, 3 m) errors
east and north. Vehicles: :func:`~roadcollab.models.vehicle.sample_fleet` with the default spread.
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

__all__ = ["CITY_ORIGIN", "CITY_ROADS", "CITY_POTHOLES", "ROUTE_SPEEDS", "SERVICE_SPEEDS", "CityTruth",
           "city_network", "city_profiles", "default_potholes", "simulate_city", "network_geojson", "write_city"]

CITY_ORIGIN = (48.137, 11.575)   # lat, lon (degrees)
#: Road positions in metres east/north of the origin.
CITY_ROADS = {"main": [(0.0, 0.0), (300.0, 0.0), (600.0, 0.0)], "cross": [(600.0, 0.0), (600.0, -500.0)],
              "service": [(0.0, 10.0), (600.0, 10.0)]}
#: (road, measure of the centre m, track, depth m, length m) of every pothole.
CITY_POTHOLES = (("main", 150.0, "both", 0.05, 0.6), ("main", 420.0, "left", 0.04, 0.5),
                 ("cross", 230.0, "right", 0.06, 0.8), ("cross", 380.0, "both", 0.035, 0.5),
                 ("service", 330.0, "both", 0.05, 0.6))
ROUTE_SPEEDS = (12.0, 15.0, 18.0, (13.0, 17.0), 14.0)
SERVICE_SPEEDS = (15.0, 16.0)
SAMPLE_RATE = 100.0
GPS_RATE = 5.0
GPS_SIGMA = 3.0
_ROUTE = ("main", "cross")


@dataclass(frozen=True, eq=False)
class CityTruth:
    """What the simulation knows.

    Attributes
    ----------
    network : RoadNetwork
    profiles : dict
        ``{route: RoadProfile}`` with ``route`` the roads' ids joined by ``+``: ``"main+cross"`` runs
        ``main`` (measure = route distance) then ``cross`` (measure = route distance - 600 m).
    road_start : dict
        ``{road_id: (route, start_m)}``: where each road lies on its route's profile.
    potholes : tuple
        ``(road_id, measure_m, side, depth_m, length_m)`` of every pothole.
    drives : list of Drive
        As simulated (positions = true route or road distance), with GPS fixes.
    roads_driven : list of tuple
        The roads each drive travels.
    """

    network: RoadNetwork
    profiles: dict
    road_start: dict
    potholes: tuple
    drives: list
    roads_driven: list

    def road_profile(self, road_id: str) -> tuple[np.ndarray, np.ndarray]:
        """Measure (m) and (n, 2) elevation (m) of one road's true profile.

        Parameters
        ----------
        road_id : str

        Returns
        -------
        measure, elevation : ndarray
        """
        route, start = self.road_start[road_id]
        p = self.profiles[route]
        keep = (p.distance >= start - 1e-9) & (p.distance <= start + self.network.roads[road_id].length + 1e-9)
        return np.asarray(p.distance[keep]) - start, np.asarray(p.elevation[keep])

    def potholes_lonlat(self) -> list[dict]:
        """Every pothole: road, measure, lon, lat, depth (m).

        Returns
        -------
        list of dict
        """
        out = []
        for road, m, side, depth, _length in self.potholes:
            line = self.network.roads[road].line
            pt = line.interpolate(m)
            lon, lat = self.network.projection.to_lonlat(pt.x, pt.y)
            out.append({"road_id": road, "measure_m": m, "lon": float(lon), "lat": float(lat), "depth_m": depth,
                        "side": side})
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


def city_profiles(network: RoadNetwork, routes, potholes, *, rng=None) -> tuple[dict, dict]:
    """The true profiles of every route (module docstring).

    Parameters
    ----------
    network : RoadNetwork
    routes : sequence of tuple
        Each a sequence of road ids driven one after the other.
    potholes : sequence of tuple
        ``(road_id, measure_m, side, depth_m, length_m)``.
    rng : numpy.random.Generator | int | None

    Returns
    -------
    profiles : dict
        ``{route name: RoadProfile}`` (ISO class B, 20 m longer than the route, with the potholes).
    road_start : dict
        ``{road_id: (route name, start_m)}``.
    """
    rng = np.random.default_rng(rng)
    profiles, road_start = {}, {}
    for route in routes:
        name = "+".join(route)
        start = 0.0
        for r in route:
            road_start[r] = (name, start)
            start += network.roads[r].length
        base = generate_road(RoadSpec(length=start + 20.0, iso_class="B", anomaly_density=0.0), rng=rng)
        on = [(m + road_start[r][1], side, depth, length) for r, m, side, depth, length in potholes if r in route]
        profiles[name] = _with_potholes(base, on)
    return profiles, road_start


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


def _gps(drive: Drive, network: RoadNetwork, roads: tuple, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """lat, lon (NaN between fixes) at GPS_RATE with N(0, GPS_SIGMA) errors east and north."""
    step = int(round(SAMPLE_RATE / GPS_RATE))
    k = np.arange(0, drive.n_samples, step)
    lines = [network.roads[r].line for r in roads]
    ends = np.cumsum([0.0] + [ln.length for ln in lines])
    xy = np.empty((k.size, 2))
    for i, p in enumerate(drive.positions[k]):
        j = min(int(np.searchsorted(ends, p, side="right")) - 1, len(lines) - 1)
        pt = lines[j].interpolate(float(p - ends[j]))
        xy[i] = (pt.x, pt.y)
    xy += rng.normal(0.0, GPS_SIGMA, xy.shape)
    lon, lat = network.projection.to_lonlat(xy[:, 0], xy[:, 1])
    full_lat, full_lon = np.full(drive.n_samples, np.nan), np.full(drive.n_samples, np.nan)
    full_lat[k], full_lon[k] = lat, lon
    return full_lat, full_lon


def simulate_city(*, seed: int = 0, network: RoadNetwork | None = None, speeds=None, vehicles: int = 3
                  ) -> tuple[CityTruth, list[tuple[np.ndarray, np.ndarray]]]:
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

    Returns
    -------
    CityTruth
    list of (lat, lon)
        Per drive, (N,) arrays with NaN between fixes.
    """
    if network is None:
        network, potholes = city_network(), CITY_POTHOLES
        plan = [(_ROUTE, v) for v in ROUTE_SPEEDS] + [(("service",), v) for v in SERVICE_SPEEDS]
    else:
        speeds = (12.0, 15.0, 18.0) if speeds is None else tuple(speeds)
        potholes = default_potholes(network)
        plan = [((rid,), speeds[j % len(speeds)]) for rid in network.roads for j in range(vehicles)]
    ss = np.random.SeedSequence(seed)
    road_rng, fleet_rng, *drive_seeds = ss.spawn(2 + len(plan))
    routes = list(dict.fromkeys(route for route, _ in plan))
    profiles, road_start = city_profiles(network, routes, potholes, rng=np.random.default_rng(road_rng))
    fleet = sample_fleet(len(plan), FleetSpec(), rng=np.random.default_rng(fleet_rng))
    drives, gps = [], []
    for j, ((route, speed), child) in enumerate(zip(plan, drive_seeds)):
        rng = np.random.default_rng(child)
        road = profiles["+".join(route)]
        end = sum(network.roads[r].length for r in route)
        d = simulate_drive(road, fleet[j], speed, start=0.0, end_margin=float(road.distance[-1]) - end + 5.0,
                           sample_rate=SAMPLE_RATE, rng=rng)
        drives.append(d)
        gps.append(_gps(d, network, route, rng))
    truth = CityTruth(network=network, profiles=profiles, road_start=road_start, potholes=tuple(potholes),
                      drives=drives, roads_driven=[route for route, _ in plan])
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


def write_city(out, *, seed: int = 0, network: RoadNetwork | None = None, speeds=None, vehicles: int = 3) -> dict:
    """Write the city: ``network.geojson``, ``drive<j>.csv`` + ``.toml`` and ``truth.json`` into ``out``.

    Parameters
    ----------
    out : Path
        An existing directory (the command stages it).
    seed, network, speeds, vehicles
        See :func:`simulate_city`.

    Returns
    -------
    dict
        ``{"network": path, "drives": [paths], "truth": path}``.
    """
    out = Path(out)
    truth, gps = simulate_city(seed=seed, network=network, speeds=speeds, vehicles=vehicles)
    net = out / "network.geojson"
    net.write_text(json.dumps(network_geojson(truth.network), indent=1))
    paths = []
    for j, (d, (lat, lon)) in enumerate(zip(truth.drives, gps), start=1):
        constant = d.speed_source == "parameters"
        p = write_gps_drive_csv(out / f"drive{j}.csv", d.time, d.accel, lat, lon,
                                column=None if constant else "speed_mps", values=None if constant else d.speeds())
        write_drive_params(out / f"drive{j}.toml", speed=d.speed if constant else None, params=d.params)
        paths.append(p)
    doc = {"seed": seed, "gps_sigma_m": GPS_SIGMA, "gps_rate_hz": GPS_RATE, "sample_rate_hz": SAMPLE_RATE,
           "roads_driven": [list(r) for r in truth.roads_driven], "potholes": truth.potholes_lonlat()}
    (out / "truth.json").write_text(json.dumps(doc, indent=1))
    return {"network": net, "drives": paths, "truth": out / "truth.json"}
