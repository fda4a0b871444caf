"""The road-condition store: segments and anomalies with their history, in SQLite (one file).

Open it with :meth:`RoadStore.open`: ``"results/roads.sqlite"`` or ``"sqlite:///abs/path.sqlite"``
(SQLite, the default), or ``"postgresql://user@host/db"`` (PostgreSQL with PostGIS, through psycopg:
the same schema, plus PostGIS ``geom`` columns; :mod:`roadcollab.store.backends`).

Schema (``schema_version`` 1 in table ``meta``)
-----------------------------------------------
``segment_records``: one row per estimate of a segment (history is kept: a new drive adds a row,
nothing is overwritten): ``road_id, direction (+1/-1), from_m, to_m, geometry`` (GeoJSON
LineString, lon/lat), ``iri_m_per_km, iri_in_per_mi, iri_low, iri_high`` (95 % interval, m/km,
NULL with one vehicle), ``n_vehicles, profile_spacing_m, profile`` (float64 little-endian, ``(n, 2)``
left/right elevation, m), ``recorded_at`` (ISO 8601 UTC), ``source``.
:meth:`RoadStore.segments` returns the latest row per segment with its first and last update.

``anomalies``: one row per anomaly on the ground, ``road_id, direction, measure_m, lon, lat, kind,
side, depth_m, votes, first_seen, last_seen``. A new detection of the same kind on the same lane
within ``merge_m`` (2 m) of one already stored is that anomaly: its votes add up, position and depth
become the vote-weighted means, ``last_seen`` moves on. Every detection is also kept in
``anomaly_records``.

Every write is one transaction (``with connection``): a crash leaves the store as it was before
the write. A file that exists and is not a roadcollab store is refused, never modified.
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .._validation import check_int, check_real
from ..errors import FileFormatError, ParameterError
from .backends import TYPES, backend_for, sqlite_path

__all__ = ["SCHEMA_VERSION", "StoredSegment", "StoredAnomaly", "RoadStore"]

SCHEMA_VERSION = 1
IN_PER_MI = 63.36
_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS segment_records (
    id {id}, road_id TEXT NOT NULL, direction INTEGER NOT NULL CHECK (direction IN (-1, 1)),
    from_m {real} NOT NULL, to_m {real} NOT NULL, geometry TEXT NOT NULL,
    iri_m_per_km {real} NOT NULL, iri_in_per_mi {real} NOT NULL, iri_low {real}, iri_high {real},
    n_vehicles INTEGER NOT NULL, profile_spacing_m {real} NOT NULL, profile {blob} NOT NULL,
    recorded_at TEXT NOT NULL, source TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS segment_key ON segment_records (road_id, direction, from_m, to_m, recorded_at);
CREATE TABLE IF NOT EXISTS anomalies (
    id {id}, road_id TEXT NOT NULL, direction INTEGER NOT NULL, measure_m {real} NOT NULL,
    lon {real} NOT NULL, lat {real} NOT NULL, kind TEXT NOT NULL, side TEXT NOT NULL, depth_m {real} NOT NULL,
    votes INTEGER NOT NULL, first_seen TEXT NOT NULL, last_seen TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS anomaly_records (
    id {id}, anomaly_id BIGINT NOT NULL REFERENCES anomalies (id), measure_m {real} NOT NULL,
    lon {real} NOT NULL, lat {real} NOT NULL, depth_m {real} NOT NULL, votes INTEGER NOT NULL,
    recorded_at TEXT NOT NULL, source TEXT NOT NULL)
"""


@dataclass(frozen=True, eq=False)
class StoredSegment:
    """A segment as stored (its latest estimate).

    Attributes
    ----------
    road_id : str
    direction : int
    from_m, to_m : float
        Road measure, m.
    lonlat : (K, 2) ndarray
        Geometry, WGS 84 degrees.
    iri_m_per_km, iri_in_per_mi : float
    iri_low, iri_high : float or None
        95 % interval, m/km.
    n_vehicles : int
    profile_spacing_m : float
    profile : (n, 2) ndarray
        Fused elevation, m.
    first_update, last_update : str
        ISO 8601 UTC.
    n_updates : int
        Rows in the history.
    """

    road_id: str
    direction: int
    from_m: float
    to_m: float
    lonlat: np.ndarray
    iri_m_per_km: float
    iri_in_per_mi: float
    iri_low: float | None
    iri_high: float | None
    n_vehicles: int
    profile_spacing_m: float
    profile: np.ndarray
    first_update: str
    last_update: str
    n_updates: int


@dataclass(frozen=True)
class StoredAnomaly:
    """An anomaly as stored.

    Attributes
    ----------
    id : int
    road_id : str
    direction : int
    measure_m, lon, lat : float
    kind, side : str
    depth_m : float
    votes : int
    first_seen, last_seen : str
    """

    id: int
    road_id: str
    direction: int
    measure_m: float
    lon: float
    lat: float
    kind: str
    side: str
    depth_m: float
    votes: int
    first_seen: str
    last_seen: str


def _now(at: str | None) -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds") if at is None else str(at)


class RoadStore:
    """The road-condition store (module docstring). Use :meth:`open`; close with :meth:`close` or ``with``.

    Parameters
    ----------
    backend : SqliteBackend or PostgresBackend
        An open database with the schema in place.
    """

    def __init__(self, backend):
        self._db = backend
        self.label = backend.label

    @staticmethod
    def path_of(url) -> Path | None:
        """Check a store URL before any work: the SQLite file, or None for a PostgreSQL URL.

        Parameters
        ----------
        url : str or Path

        Returns
        -------
        Path or None

        Raises
        ------
        ParameterError
            Another URL scheme.
        """
        text = str(url)
        return None if text.startswith(("postgresql://", "postgres://")) else sqlite_path(text)

    @classmethod
    def open(cls, url) -> "RoadStore":
        """Open (or create) a store.

        Parameters
        ----------
        url : str or Path
            A file path, ``sqlite:///path`` or ``postgresql://user@host/db`` (PostGIS).

        Returns
        -------
        RoadStore

        Raises
        ------
        FileFormatError
            The file exists and is not a roadcollab store (it is left untouched).
        ParameterError
            Another URL scheme, or a PostgreSQL server that cannot be reached.
        """
        path = cls.path_of(url)
        existed = path is not None and path.exists() and path.stat().st_size > 0
        db = backend_for(url)
        try:
            names = db.tables() if existed or path is None else set()
            ours = "meta" in names and db.query("SELECT value FROM meta WHERE key = 'schema_version'")
            if (existed or "segment_records" in names) and not (ours and ours[0][0] == str(SCHEMA_VERSION)):
                raise FileFormatError(f"{db.label}: expected a roadcollab road store (schema_version "
                                      f"{SCHEMA_VERSION}), got a database without it; not modified")
            with db.transaction():
                for statement in _SCHEMA.format(**TYPES[db.kind]).split(";"):
                    db.execute(statement)
                for key, value in (("schema_version", str(SCHEMA_VERSION)), ("application", "roadcollab")):
                    db.execute("INSERT INTO meta (key, value) VALUES (?, ?) ON CONFLICT (key) DO NOTHING",
                               (key, value))
                if db.kind == "postgresql":
                    db.add_spatial_columns()
        except sqlite3.DatabaseError as err:
            db.close()
            raise FileFormatError(f"{db.label}: expected an SQLite road store, got {err}; not modified") from None
        except BaseException:
            db.close()
            raise
        return cls(db)

    def close(self) -> None:
        """Close the connection."""
        self._db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- writing ---------------------------------------------------------------------------------

    def record_segment(self, road_id: str, direction: int, from_m: float, to_m: float, lonlat, iri_m_per_km: float,
                       *, iri_low: float | None = None, iri_high: float | None = None, n_vehicles: int = 1,
                       profile=None, profile_spacing_m: float = 0.05, source: str = "", at: str | None = None) -> int:
        """Add an estimate of a segment (the history keeps the earlier ones).

        Parameters
        ----------
        road_id : str
        direction : {1, -1}
        from_m, to_m : float
            Road measure, m, ``from_m < to_m``.
        lonlat : (K, 2) array_like
            Geometry, WGS 84 ``[lon, lat]``.
        iri_m_per_km : float
        iri_low, iri_high : float, optional
            95 % interval, m/km (NaN is stored as NULL).
        n_vehicles : int
        profile : (n, 2) array_like, optional
            Fused elevation, m.
        profile_spacing_m : float
        source : str
            Who wrote it (e.g. the command line).
        at : str, optional
            ISO 8601 time; default now (UTC).

        Returns
        -------
        int
            The row id.
        """
        check_int("direction", direction, low=-1, high=1)
        if direction == 0 or not from_m < to_m:
            raise ParameterError(f"direction must be +1 or -1 and from_m < to_m, got {direction}, {from_m}, {to_m}")
        check_real("iri_m_per_km", iri_m_per_km, low=0.0)
        geom = json.dumps({"type": "LineString", "coordinates": np.asarray(lonlat, float).tolist()})
        prof = np.zeros((0, 2)) if profile is None else np.asarray(profile, "<f8").reshape(-1, 2)

        def opt(v):
            return None if v is None or not np.isfinite(v) else float(v)

        with self._db.transaction():
            rid = self._db.insert(
                "INSERT INTO segment_records (road_id, direction, from_m, to_m, geometry, iri_m_per_km, iri_in_per_mi,"
                " iri_low, iri_high, n_vehicles, profile_spacing_m, profile, recorded_at, source)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (str(road_id), int(direction), float(from_m), float(to_m), geom, float(iri_m_per_km),
                 float(iri_m_per_km) * IN_PER_MI, opt(iri_low), opt(iri_high), int(n_vehicles),
                 float(profile_spacing_m), prof.astype("<f8").tobytes(), _now(at), str(source)))
            self._db.spatial("segment_records", rid)
        return rid

    def record_anomaly(self, road_id: str, direction: int, measure_m: float, lon: float, lat: float, kind: str,
                       side: str, depth_m: float, votes: int = 1, *, merge_m: float = 2.0, source: str = "",
                       at: str | None = None) -> int:
        """Add a detection; merged into a stored anomaly of the same kind within ``merge_m`` on the lane.

        Parameters
        ----------
        road_id : str
        direction : {1, -1}
        measure_m : float
            Road measure of the centre, m.
        lon, lat : float
            WGS 84 degrees.
        kind, side : str
            ``pothole``/``bump``; ``left``/``right``/``both``.
        depth_m : float
        votes : int
            Vehicles that saw it.
        merge_m : float
            m.
        source : str
        at : str, optional
            ISO 8601 time; default now (UTC).

        Returns
        -------
        int
            The anomaly's id.
        """
        votes = check_int("votes", votes, low=1)
        t = _now(at)
        with self._db.transaction():
            rows = self._db.query(
                "SELECT id, measure_m, lon, lat, depth_m, votes FROM anomalies WHERE road_id = ? AND direction = ?"
                " AND kind = ? AND abs(measure_m - ?) <= ? ORDER BY abs(measure_m - ?) LIMIT 1",
                (road_id, int(direction), kind, float(measure_m), float(merge_m), float(measure_m)))
            if not rows:
                aid = self._db.insert(
                    "INSERT INTO anomalies (road_id, direction, measure_m, lon, lat, kind, side, depth_m, votes,"
                    " first_seen, last_seen) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (road_id, int(direction), float(measure_m), float(lon), float(lat), kind, side, float(depth_m),
                     votes, t, t))
            else:
                aid, m0, lon0, lat0, d0, v0 = rows[0]
                w = v0 + votes

                def mix(a, b):
                    return (a * v0 + b * votes) / w

                self._db.execute("UPDATE anomalies SET measure_m = ?, lon = ?, lat = ?, depth_m = ?, votes = ?,"
                                 " last_seen = ? WHERE id = ?",
                                 (mix(m0, measure_m), mix(lon0, lon), mix(lat0, lat), mix(d0, depth_m), w, t, aid))
            self._db.spatial("anomalies", aid)
            self._db.execute("INSERT INTO anomaly_records (anomaly_id, measure_m, lon, lat, depth_m, votes,"
                             " recorded_at, source) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                             (aid, float(measure_m), float(lon), float(lat), float(depth_m), votes, t, source))
        return aid

    # --- reading ---------------------------------------------------------------------------------

    def segments(self) -> list[StoredSegment]:
        """The latest estimate of every segment, ordered by road, direction and measure.

        Returns
        -------
        list of StoredSegment
        """
        rows = self._db.query(
            "SELECT r.road_id, r.direction, r.from_m, r.to_m, r.geometry, r.iri_m_per_km, r.iri_in_per_mi, r.iri_low,"
            " r.iri_high, r.n_vehicles, r.profile_spacing_m, r.profile, k.first_at, k.last_at, k.n FROM segment_records r"
            " JOIN (SELECT road_id, direction, from_m, to_m, MIN(recorded_at) AS first_at, MAX(recorded_at) AS last_at,"
            " MAX(id) AS latest, COUNT(*) AS n FROM segment_records GROUP BY road_id, direction, from_m, to_m) k"
            " ON r.id = k.latest ORDER BY r.road_id, r.direction DESC, r.from_m")
        return [self._segment(r) for r in rows]

    @staticmethod
    def _segment(r) -> StoredSegment:
        return StoredSegment(road_id=r[0], direction=r[1], from_m=r[2], to_m=r[3],
                             lonlat=np.array(json.loads(r[4])["coordinates"], float), iri_m_per_km=r[5],
                             iri_in_per_mi=r[6], iri_low=r[7], iri_high=r[8], n_vehicles=r[9],
                             profile_spacing_m=r[10], profile=np.frombuffer(r[11], "<f8").reshape(-1, 2).copy(),
                             first_update=r[12], last_update=r[13], n_updates=r[14])

    def anomalies(self) -> list[StoredAnomaly]:
        """Every anomaly, ordered by road, direction and measure.

        Returns
        -------
        list of StoredAnomaly
        """
        rows = self._db.query("SELECT id, road_id, direction, measure_m, lon, lat, kind, side, depth_m, votes,"
                              " first_seen, last_seen FROM anomalies ORDER BY road_id, direction DESC, measure_m")
        return [StoredAnomaly(*r) for r in rows]

    def history(self, road_id: str, direction: int | None = None, from_m: float | None = None) -> list[dict]:
        """Every stored estimate of a road's segments, oldest first.

        Parameters
        ----------
        road_id : str
        direction : int, optional
            Only this direction.
        from_m : float, optional
            Only the segment starting here (m).

        Returns
        -------
        list of dict
            ``road_id, direction, from_m, to_m, iri_m_per_km, iri_low, iri_high, n_vehicles, recorded_at, source``.
        """
        sql = ("SELECT road_id, direction, from_m, to_m, iri_m_per_km, iri_low, iri_high, n_vehicles, recorded_at,"
               " source FROM segment_records WHERE road_id = ?")
        args: list = [road_id]
        if direction is not None:
            sql += " AND direction = ?"
            args.append(int(direction))
        if from_m is not None:
            sql += " AND abs(from_m - ?) < 1e-6"
            args.append(float(from_m))
        keys = ("road_id", "direction", "from_m", "to_m", "iri_m_per_km", "iri_low", "iri_high", "n_vehicles",
                "recorded_at", "source")
        return [dict(zip(keys, r)) for r in self._db.query(sql + " ORDER BY id", args)]
