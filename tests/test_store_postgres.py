"""The road store on PostgreSQL/PostGIS: a throw-away server on 127.0.0.1, the same API as SQLite, and the
PostGIS geometry a GIS would query. Needs the Debian packages postgresql and postgresql-15-postgis-3."""

import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from roadcollab.store import RoadStore

pytestmark = pytest.mark.slow
PG_BIN = Path("/usr/lib/postgresql/15/bin")
LINE = np.array([[11.575, 48.137], [11.576, 48.137], [11.577, 48.1371]])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def pg_url():
    if not (PG_BIN / "initdb").exists():
        if os.environ.get("CI"):
            pytest.fail("CI needs apt-get install -y postgresql postgresql-15-postgis-3")
        pytest.skip("PostgreSQL 15 is not installed")
    root = Path(tempfile.mkdtemp(prefix="roadcollab-pg-"))
    as_user = []
    if os.geteuid() == 0:                      # the server refuses to run as root
        pw = pwd.getpwnam("postgres")
        os.chown(root, pw.pw_uid, pw.pw_gid)
        as_user = ["runuser", "-u", "postgres", "--"]
    port = _free_port()
    data = root / "data"
    subprocess.run(as_user + [str(PG_BIN / "initdb"), "-D", str(data), "-A", "trust", "-U", "postgres"],
                   check=True, capture_output=True, timeout=120)
    opts = f"-p {port} -k {root} -c listen_addresses=127.0.0.1"
    subprocess.run(as_user + [str(PG_BIN / "pg_ctl"), "-D", str(data), "-o", opts, "-w", "-t", "60", "-l",
                              str(root / "log"), "start"], check=True, capture_output=True, timeout=90)
    try:
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run(as_user + [str(PG_BIN / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop"],
                       capture_output=True, timeout=60)
        shutil.rmtree(root, ignore_errors=True)


def test_same_api_on_postgis(pg_url):
    import psycopg
    prof = np.cumsum(np.random.default_rng(0).normal(0, 1e-3, (400, 2)), axis=0)
    with RoadStore.open(pg_url) as s:
        s.record_segment("main", 1, 0.0, 100.0, LINE, 3.0, iri_low=2.5, iri_high=3.5, n_vehicles=4, profile=prof,
                         source="a", at="2026-01-01T00:00:00+00:00")
        s.record_segment("main", 1, 0.0, 100.0, LINE, 3.2, n_vehicles=6, profile=prof, source="b",
                         at="2026-02-01T00:00:00+00:00")
        s.record_anomaly("main", 1, 50.0, 11.5757, 48.137, "pothole", "both", 0.04, 3, at="2026-01-01T00:00:00+00:00")
        s.record_anomaly("main", 1, 51.0, 11.5758, 48.137, "pothole", "both", 0.06, 1, at="2026-02-01T00:00:00+00:00")
    with RoadStore.open(pg_url) as s:                    # opened again: the schema is found, not recreated
        (seg,) = s.segments()
        (an,) = s.anomalies()
        hist = s.history("main", 1, 0.0)
    assert seg.iri_m_per_km == 3.2 and seg.n_updates == 2 and seg.iri_low is None
    assert np.array_equal(seg.profile, prof) and np.allclose(seg.lonlat, LINE)   # float64, not PostgreSQL's REAL
    assert an.votes == 4 and an.measure_m == pytest.approx(50.25)
    assert [h["source"] for h in hist] == ["a", "b"]
    with psycopg.connect(pg_url) as db:
        length = db.execute("SELECT ST_Length(geom::geography) FROM segment_records ORDER BY id LIMIT 1").fetchone()[0]
        srid = db.execute("SELECT ST_SRID(geom) FROM anomalies").fetchone()[0]
    from roadcollab.geo.projection import geodesic_m
    expect = float(np.sum(geodesic_m(LINE[:-1, 0], LINE[:-1, 1], LINE[1:, 0], LINE[1:, 1])))
    assert srid == 4326 and abs(length - expect) < 0.01                  # PostGIS's geodesic length, same ellipsoid


def test_postgres_database_with_foreign_tables_is_refused(pg_url):
    import psycopg
    from roadcollab import ParameterError
    with psycopg.connect(pg_url, autocommit=True) as db:
        db.execute("CREATE DATABASE other")
    other = pg_url.rsplit("/", 1)[0] + "/other"
    with psycopg.connect(other, autocommit=True) as db:
        db.execute("CREATE TABLE segment_records (x int)")
    with pytest.raises(ParameterError, match="expected a roadcollab road store"):
        RoadStore.open(other)
