"""The service store on PostgreSQL (``serve --store postgresql://...``): a throw-away Debian PostgreSQL 15 on
127.0.0.1 (the fixture of test_store_postgres.py), the same results as the SQLite file, and two
``serve --shared`` against one Mosquitto and one database giving the equality of issue 19."""

import numpy as np
import pytest

from netkit import HAVE_MOSQUITTO, free_port, start_mosquitto, start_serve, stop, write_drives
from roadcollab import ParameterError
from roadcollab.io.drive_clean import clean_drive
from roadcollab.io.drives import load_drives
from roadcollab.network.memory import run_in_memory
from roadcollab.network.pgstore import PostgresServiceStore, open_service_store
from roadcollab.network.plan import RoadPlan
from roadcollab.network.results import results_from_store
from roadcollab.network.store import ServiceStore
from test_network_mqtt import _export_equal, _fleet, world  # noqa: F401 (fixture)
from test_store_postgres import pg_url  # noqa: F401 (fixture)

pytestmark = pytest.mark.slow


def _database(pg_url, name):  # noqa: F811
    import psycopg

    with psycopg.connect(pg_url, autocommit=True) as db:
        db.execute(f"DROP DATABASE IF EXISTS {name}")
        db.execute(f"CREATE DATABASE {name}")
    return pg_url.rsplit("/", 1)[0] + "/" + name


def test_postgres_store_equals_the_sqlite_file(pg_url, tmp_path):  # noqa: F811
    paths, _ = write_drives(tmp_path / "drives", speeds=(12.0, 15.0))
    drives = [clean_drive(d)[0] for d in load_drives(paths)]
    plan = RoadPlan(fleet_id="t", min_speed=min(float(d.speeds().min()) for d in drives))
    url = _database(pg_url, "svc_equal")
    pg = open_service_store(url, plan)
    assert isinstance(pg, PostgresServiceStore)
    run_in_memory(drives, plan, store=pg)
    lite, _ = run_in_memory(drives, plan, store=ServiceStore(tmp_path / "s.sqlite", plan))
    a, b = results_from_store(pg), results_from_store(lite)
    assert np.array_equal(a.fused, b.fused, equal_nan=True) and np.array_equal(a.coverage, b.coverage)
    for k in a.elevation:
        assert np.array_equal(a.elevation[k], b.elevation[k], equal_nan=True)
    assert pg.status() == lite.status()
    assert pg.status()["contributions"] == 12
    pg.close()
    again = open_service_store(url)                  # reopened: the plan is read back, the counts kept
    assert again.plan == plan and again.status()["contributions"] == 12
    run_in_memory(drives, plan, store=again)         # the vehicles again: told their segments are done
    assert again.status()["contributions"] == 12 and again.status()["refused"] == {}
    again.close()
    with pytest.raises(ParameterError, match="another fleet plan"):
        open_service_store(url, RoadPlan(fleet_id="other", min_speed=plan.min_speed))
    with pytest.raises(ParameterError, match="cannot connect to PostgreSQL"):
        open_service_store(f"postgresql://postgres@127.0.0.1:{free_port()}/x")


@pytest.mark.skipif(not HAVE_MOSQUITTO, reason="apt-get install -y mosquitto")
def test_two_services_on_one_postgres_database(world, pg_url, tmp_path):  # noqa: F811
    """Two ``serve --shared`` against one Mosquitto and one PostgreSQL database: the equality holds."""
    root, drives = world
    url = _database(pg_url, "svc_shared")
    port = free_port()
    broker = f"mqtt://127.0.0.1:{port}"
    mosq = start_mosquitto(root / "fleet", port, tmp_path / "mosq", tmp_path / "broker.log")
    a = start_serve(root / "fleet", url, tmp_path / "a.log", broker=broker, shared=True)
    b = start_serve(root / "fleet", url, tmp_path / "b.log", broker=broker, shared=True)
    try:
        _fleet(root, drives, broker, "--concurrent")
    finally:
        codes = [stop(a), stop(b)]
        stop(mosq)
    assert codes == [0, 0]
    assert _export_equal(root, url, tmp_path / "out", skip=("elevation_collaborative",)) <= 1e-9
    logs = [(tmp_path / f).read_text() for f in ("a.log", "b.log")]
    assert all("accepted" in t for t in logs), "both services applied contributions"
