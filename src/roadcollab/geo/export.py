"""Files a GIS and a road agency open: GeoJSON, GeoPackage, linear-reference CSV, OpenCRG.

The writers take the store's records (:class:`~roadcollab.store.StoredSegment` and
:class:`~roadcollab.store.StoredAnomaly`, or any objects with the same attributes).

* ``segments.geojson``, ``anomalies.geojson``: RFC 7946 FeatureCollections, positions
  ``[lon, lat]`` (WGS 84, section 4), LineStrings of at least two positions (3.1.4), no ``crs``
  member (removed by RFC 7946), coordinates rounded to 1e-7 degrees (1 cm; section 11.2 advises
  against more precision than the data has).
* ``roads.gpkg``: a GeoPackage with layers ``segments`` and ``anomalies`` (EPSG:4326), written by
  pyogrio (GDAL's OGR driver), not by hand-written SQL.
* ``segments.csv``: linear-reference events ``road_id, direction, from_m, to_m, iri_m_per_km, ...``
  (the table a road agency's linear-referencing system joins to its route network).
* ``<road>_<dir>_<from>.crg``: a segment's fused profile as an OpenCRG road (pyopencrg, text format
  LDFI): reference line along ``u`` (m, direction of travel), two lateral positions ``v = -0.75,
  +0.75`` m carrying the right and left wheel-track elevations (OpenCRG's ``v`` is positive to the
  left), so a simulator drives the estimated road; a flat cross-section between the tracks is the
  linear interpolation OpenCRG makes between the two columns.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyopencrg
import shapely
from pyogrio.raw import write as write_raw
from shapely.geometry import LineString, Point

from ..errors import ParameterError

__all__ = ["SEGMENT_FIELDS", "ANOMALY_FIELDS", "TRACK_HALF_WIDTH", "segments_geojson", "anomalies_geojson",
           "write_geojson", "write_geopackage", "write_segment_csv", "write_opencrg"]

SEGMENT_FIELDS = ("road_id", "direction", "from_m", "to_m", "iri_m_per_km", "iri_in_per_mi", "iri_low", "iri_high",
                  "n_vehicles", "first_update", "last_update")
ANOMALY_FIELDS = ("id", "road_id", "direction", "measure_m", "lon", "lat", "kind", "side", "depth_m", "votes",
                  "first_seen", "last_seen")
TRACK_HALF_WIDTH = 0.75   # m: half the wheel-track spacing of the OpenCRG cross-section
_PLACES = 7


def _value(v):
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return None if not np.isfinite(v) else float(v)
    return v


def segments_geojson(segments) -> dict:
    """Segments as an RFC 7946 FeatureCollection of LineStrings.

    Parameters
    ----------
    segments : sequence of StoredSegment

    Returns
    -------
    dict
    """
    feats = []
    for s in segments:
        coords = np.round(np.asarray(s.lonlat, float), _PLACES).tolist()
        feats.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
                      "properties": {k: _value(getattr(s, k)) for k in SEGMENT_FIELDS}})
    return {"type": "FeatureCollection", "features": feats}


def anomalies_geojson(anomalies) -> dict:
    """Anomalies as an RFC 7946 FeatureCollection of Points.

    Parameters
    ----------
    anomalies : sequence of StoredAnomaly

    Returns
    -------
    dict
    """
    feats = [{"type": "Feature",
              "geometry": {"type": "Point", "coordinates": [round(float(a.lon), _PLACES), round(float(a.lat), _PLACES)]},
              "properties": {k: _value(getattr(a, k)) for k in ANOMALY_FIELDS}} for a in anomalies]
    return {"type": "FeatureCollection", "features": feats}


def write_geojson(path, collection: dict) -> Path:
    """Write a FeatureCollection (UTF-8, no NaN: RFC 8259 has none).

    Parameters
    ----------
    path : str or Path
    collection : dict

    Returns
    -------
    Path
    """
    path = Path(path)
    path.write_text(json.dumps(collection, allow_nan=False, indent=None, separators=(",", ":")) + "\n",
                    encoding="utf-8")
    return path


def _columns(records, fields) -> dict:
    out = {}
    for k in fields:
        vals = [_value(getattr(r, k)) for r in records]
        if all(isinstance(v, str) for v in vals):
            out[k] = np.array(vals, dtype=object)
        elif all(isinstance(v, int) and not isinstance(v, bool) for v in vals):
            out[k] = np.array(vals, dtype=np.int64)
        else:
            out[k] = np.array([np.nan if v is None else v for v in vals], dtype=np.float64)
    return out


def write_geopackage(path, segments, anomalies) -> Path:
    """A GeoPackage with layers ``segments`` (LineString) and ``anomalies`` (Point), EPSG:4326.

    Parameters
    ----------
    path : str or Path
        Written anew (an existing file of that name is replaced: the command writes into a staging folder).
    segments : sequence of StoredSegment
    anomalies : sequence of StoredAnomaly

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        No segments (a layer needs at least one feature to carry its fields).
    """
    path = Path(path)
    if not segments:
        raise ParameterError("no segments to write into the GeoPackage")
    seg_geom = shapely.to_wkb([LineString(np.asarray(s.lonlat, float)) for s in segments])
    seg_cols = _columns(segments, SEGMENT_FIELDS)
    # pyogrio's raw writer takes WKB and numpy columns: no geopandas needed
    write_raw(path, seg_geom, list(seg_cols.values()), list(seg_cols), layer="segments", driver="GPKG",
             geometry_type="LineString", crs="EPSG:4326")
    if anomalies:
        an_geom = shapely.to_wkb([Point(float(a.lon), float(a.lat)) for a in anomalies])
        an_cols = _columns(anomalies, ANOMALY_FIELDS)
        write_raw(path, an_geom, list(an_cols.values()), list(an_cols), layer="anomalies", driver="GPKG",
                 geometry_type="Point", crs="EPSG:4326", append=False)
    return path


def write_segment_csv(path, segments) -> Path:
    """Linear-reference events, one row per segment (module docstring).

    Parameters
    ----------
    path : str or Path
    segments : sequence of StoredSegment

    Returns
    -------
    Path
    """
    path = Path(path)
    lines = [",".join(SEGMENT_FIELDS)]
    for s in segments:
        row = []
        for k in SEGMENT_FIELDS:
            v = _value(getattr(s, k))
            row.append("" if v is None else (repr(v) if isinstance(v, float) else str(v)))
        lines.append(",".join(row))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_opencrg(path, segment) -> Path:
    """A segment's fused profile as an OpenCRG file (module docstring).

    Parameters
    ----------
    path : str or Path
    segment : StoredSegment
        With a profile of at least two points.

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        A profile with fewer than two points.
    """
    prof = np.asarray(segment.profile, float)
    if prof.shape[0] < 2:
        raise ParameterError(f"segment {segment.road_id} {segment.from_m:g}-{segment.to_m:g} m has no profile to write")
    z = np.column_stack([prof[:, 1], prof[:, 0]])               # columns in increasing v: right (-), left (+)
    road = pyopencrg.CrgRoad(z, float(segment.profile_spacing_m), np.array([-TRACK_HALF_WIDTH, TRACK_HALF_WIDTH]),
                             comments=[f"roadcollab fused profile, road {segment.road_id}, direction "
                                       f"{segment.direction:+d}, measure {segment.from_m:g}-{segment.to_m:g} m"])
    path = Path(path)
    road.save(str(path), fmt="LDFI")
    return path
