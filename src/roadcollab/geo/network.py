"""A road network: GeoJSON LineStrings with a ``road_id``, in a local metric projection.

File format (``--network FILE``)
--------------------------------
An RFC 7946 GeoJSON ``FeatureCollection`` whose features are ``LineString`` geometries with a
``road_id`` property (a non-empty string or an integer, unique), positions ``[lon, lat]`` in WGS 84
degrees (a third coordinate is ignored). The road's measure (linear referencing, m) runs from its
first position to its last: that is the road's *forward* direction. Roads meet at junctions where
their end points coincide (within :data:`JUNCTION_TOLERANCE`), and at T-junctions where a road's end
point lies on another road's interior (within the same tolerance): the through road is not split, its
measure runs on, and the junction is a node at its measure there. The map matcher routes through them.
At most 10 MB, 10,000 roads.

Without a network, a drive's own GPS track is its road (:func:`track_road`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path
from shapely.geometry import LineString

from ..errors import FileFormatError, ParameterError
from ..io.limits import check_file_size, short_repr
from .projection import LocalProjection

__all__ = ["JUNCTION_TOLERANCE", "MAX_ROADS", "Road", "RoadNetwork", "read_network", "network_from_lonlat",
           "track_road"]

JUNCTION_TOLERANCE = 1.0      # m: end points this close are one junction
MAX_ROADS = 10_000
_MAX_BYTES = 10_000_000


@dataclass(frozen=True, eq=False)
class Road:
    """One road of the network.

    Attributes
    ----------
    road_id : str
    lonlat : (K, 2) ndarray
        Its positions, WGS 84 degrees ``[lon, lat]``.
    line : shapely.LineString
        The same in the network's projection, m.
    """

    road_id: str
    lonlat: np.ndarray
    line: LineString

    @property
    def length(self) -> float:
        """Length along the road, m."""
        return float(self.line.length)


@dataclass(frozen=True, eq=False)
class RoadNetwork:
    """Roads in one local projection, with the junction graph between their end points.

    Attributes
    ----------
    roads : dict
        ``{road_id: Road}``, in file order.
    projection : LocalProjection
        Centred on the mean of every position.
    nodes_on : dict
        ``{road_id: ((measure_m, node), ...)}``: the junction nodes on each road in measure order, its two
        ends first and last, T-junctions onto its interior between.
    node_distance : (J, J) ndarray
        Shortest distance along the roads between junction nodes, m (inf if not connected).
    """

    roads: dict
    projection: LocalProjection
    nodes_on: dict
    node_distance: np.ndarray

    def road(self, road_id: str) -> Road:
        """The road ``road_id``.

        Parameters
        ----------
        road_id : str

        Returns
        -------
        Road
        """
        return self.roads[road_id]

    def route_m(self, road_a: str, m_a: float, road_b: str, m_b: float) -> float:
        """Shortest distance along the roads from measure ``m_a`` of ``road_a`` to ``m_b`` of ``road_b``, m.

        Parameters
        ----------
        road_a, road_b : str
        m_a, m_b : float
            Measures, m.

        Returns
        -------
        float
            ``|m_b - m_a|`` on one road; otherwise through the junctions on both roads (their ends and
            T-junctions; inf if not connected).
        """
        if road_a == road_b:
            return abs(m_b - m_a)
        best = np.inf
        for ma, na in self.nodes_on[road_a]:
            for mb, nb in self.nodes_on[road_b]:
                best = min(best, abs(m_a - ma) + self.node_distance[na, nb] + abs(m_b - mb))
        return float(best)


def _junctions(lines: list[LineString]) -> tuple[list[list[tuple[float, int]]], np.ndarray]:
    """Junction nodes on every road (ends merged within JUNCTION_TOLERANCE, T-junctions onto interiors) and
    the all-pairs distances between nodes along the roads."""
    nodes: list[np.ndarray] = []

    def node(p: np.ndarray) -> int:
        hit = next((i for i, q in enumerate(nodes) if np.hypot(*(p - q)) <= JUNCTION_TOLERANCE), None)
        if hit is None:
            nodes.append(p)
            hit = len(nodes) - 1
        return hit

    on: list[list[tuple[float, int]]] = []
    for line in lines:
        c = np.asarray(line.coords)
        on.append([(0.0, node(c[0][:2])), (float(line.length), node(c[-1][:2]))])
    # T-junctions: an end point on another road's interior (farther than the tolerance from its ends)
    for line, ends in zip(lines, list(on)):
        for _m, n in ends:
            pt = shapely.Point(nodes[n])
            for other, lst in zip(lines, on):
                if other is line or other.distance(pt) > JUNCTION_TOLERANCE:
                    continue
                m = float(other.project(pt))
                if JUNCTION_TOLERANCE < m < other.length - JUNCTION_TOLERANCE and all(k != n for _, k in lst):
                    lst.append((m, n))
    on = [sorted(lst) for lst in on]
    J = len(nodes)
    weight = np.full((J, J), np.inf)
    for lst in on:
        for (ma, a), (mb, b) in zip(lst, lst[1:]):
            if a != b:
                weight[a, b] = weight[b, a] = min(weight[a, b], mb - ma)
    graph = csr_matrix(np.where(np.isfinite(weight), weight, 0.0))
    return on, shortest_path(graph, directed=False)


def network_from_lonlat(roads: dict) -> RoadNetwork:
    """A network from ``{road_id: (K, 2) array of [lon, lat]}``.

    Parameters
    ----------
    roads : dict
        Positions of every road in WGS 84 degrees, at least two distinct ones each.

    Returns
    -------
    RoadNetwork

    Raises
    ------
    ParameterError
        No roads, or a road with fewer than two distinct positions.
    """
    if not roads:
        raise ParameterError("a road network needs at least one road, got none")
    allpts = np.concatenate([np.asarray(v, float) for v in roads.values()])
    proj = LocalProjection(float(np.mean(allpts[:, 1])), float(np.mean(allpts[:, 0])))
    out = {}
    for rid, pts in roads.items():
        pts = np.asarray(pts, float)
        x, y = proj.to_xy(pts[:, 0], pts[:, 1])
        line = LineString(np.column_stack([x, y]))
        if line.length <= 0:
            raise ParameterError(f"road {rid!r}: expected at least two distinct positions, got a zero-length line")
        out[rid] = Road(road_id=rid, lonlat=pts, line=line)
    on, dist = _junctions([r.line for r in out.values()])
    nodes_on = {rid: tuple(lst) for rid, lst in zip(out, on)}
    return RoadNetwork(roads=out, projection=proj, nodes_on=nodes_on, node_distance=dist)


def _feature_road(path: Path, i: int, feat) -> tuple[str, np.ndarray]:
    where = f"{path}: features[{i}]"
    if not isinstance(feat, dict) or feat.get("type") != "Feature":
        raise FileFormatError(f"{where}: expected a GeoJSON Feature object, got {short_repr(feat)}")
    geom, props = feat.get("geometry"), feat.get("properties")
    rid = props.get("road_id") if isinstance(props, dict) else None
    if isinstance(rid, bool) or not isinstance(rid, (str, int)) or not str(rid).strip():
        raise FileFormatError(f"{where}.properties.road_id: expected a non-empty string or an integer, got "
                              f"{short_repr(rid)}")
    if not isinstance(geom, dict) or geom.get("type") != "LineString":
        kind = geom.get("type") if isinstance(geom, dict) else geom
        raise FileFormatError(f"{where}.geometry: expected a LineString, got {short_repr(kind)}")
    coords = geom.get("coordinates")
    try:
        if not isinstance(coords, list):
            raise TypeError(coords)
        pts = np.array([[float(c[0]), float(c[1])] for c in coords], dtype=float)
    except (TypeError, ValueError, IndexError, KeyError):
        raise FileFormatError(f"{where}.geometry.coordinates: expected a list of [lon, lat] numbers") from None
    if pts.shape[0] < 2 or not np.all(np.isfinite(pts)) or np.any(np.abs(pts[:, 0]) > 180) \
            or np.any(np.abs(pts[:, 1]) > 90):
        raise FileFormatError(f"{where}.geometry.coordinates: expected at least two [lon, lat] positions with "
                              f"|lon| <= 180 and |lat| <= 90 (RFC 7946 order: longitude first), got "
                              f"{short_repr(coords)}")
    return str(rid), pts


def read_network(path) -> RoadNetwork:
    """Read and validate a road network file (module docstring).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    RoadNetwork

    Raises
    ------
    FileFormatError
        ``"<path>: ..."`` naming the feature and field that is wrong.
    """
    path = Path(path)
    check_file_size(path, "road network", _MAX_BYTES, flag=None)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise FileFormatError(f"{path}: expected a GeoJSON (UTF-8 JSON) file, got {err}") from None
    feats = doc.get("features") if isinstance(doc, dict) and doc.get("type") == "FeatureCollection" else None
    if not isinstance(feats, list) or not feats or len(feats) > MAX_ROADS:
        raise FileFormatError(f"{path}: expected a GeoJSON FeatureCollection of 1-{MAX_ROADS} LineString features "
                              "with a road_id property")
    roads = {}
    for i, feat in enumerate(feats):
        rid, pts = _feature_road(path, i, feat)
        if rid in roads:
            raise FileFormatError(f"{path}: features[{i}].properties.road_id: {rid!r} is used twice; expected "
                                  "unique road ids")
        roads[rid] = pts
    try:
        return network_from_lonlat(roads)
    except ParameterError as err:
        raise FileFormatError(f"{path}: {err}") from None


def track_road(road_id: str, lon, lat, *, window: int = 9) -> np.ndarray:
    """A road from a drive's own GPS track: the fixes smoothed by a centred moving average.

    Parameters
    ----------
    road_id : str
        Name of the road (used in messages).
    lon, lat : (F,) array_like
        Fixes, degrees.
    window : int
        Moving-average width in fixes (odd; 9 fixes at 5 Hz average 1.8 s, about 25 m at 15 m/s).

    Returns
    -------
    (K, 2) ndarray
        ``[lon, lat]`` of the smoothed track, simplified to 0.1 m (pass it to :func:`network_from_lonlat`).

    Raises
    ------
    ParameterError
        Fewer than two fixes.
    """
    lon, lat = np.asarray(lon, float), np.asarray(lat, float)
    if lon.shape[0] < 2:
        raise ParameterError(f"road {road_id!r}: a GPS track needs at least two fixes, got {lon.shape[0]}")
    w = max(1, min(window, lon.shape[0] // 2 * 2 - 1))
    kern = np.ones(w) / w
    pad = w // 2
    sm = [np.convolve(np.pad(c, pad, mode="edge"), kern, mode="valid") for c in (lon, lat)]
    line = shapely.simplify(LineString(np.column_stack(sm)), 1e-6)
    return np.asarray(line.coords)
