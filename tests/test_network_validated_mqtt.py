"""Validated aggregation as a fleet mode, between separate processes over a real broker on 127.0.0.1 (issue 20).

A fleet enrolled with ``--aggregation validated``: ``serve`` leads every segment's phased validated session,
two ``roadcollab helper`` processes (other operators', from the ``helper/`` and ``helper-c/`` folders ``enroll``
wrote) are the other aggregators, and every vehicle process gives each segment it covered whole to one
session. Oracles:

- ``export``'s fused elevation on those segments equals ``estimate``'s ``final_estimate.csv`` (the clear mean
  of the same drives' inversions) to the proofs' fixed point (a few ``2^-12`` m), with every point counted
  by all 4 vehicles; segments no vehicle covered whole get no estimate;
- the service's store holds no vehicle's inversion (every contribution body is sealed);
- each helper's release log holds one release per session and phase.
"""

import sqlite3

import numpy as np
import pytest
from netkit import HAVE_MOSQUITTO, PY, free_port, rc, read_csv, start, start_mosquitto, start_serve, stop, write_drives

from roadcollab.io.drives import load_drives
from roadcollab.network.store import ServiceStore

pytestmark = pytest.mark.slow

BROKERS = ["amqtt", pytest.param("mosquitto", marks=pytest.mark.skipif(not HAVE_MOSQUITTO,
                                                                        reason="apt-get install -y mosquitto"))]
VALIDATED = ("--aggregation", "validated", "--min-inputs", 3, "--round-size", 4, "--clip", 0.2, "--phases", 3,
             "--grid-step", 0.1)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("valnet")
    drives, _ = write_drives(root / "drives")
    vmin = min(float(d.speeds().min()) for d in load_drives(drives))
    rc("enroll", "--fleet", root / "fleet", "--vehicles", 4, "--fleet-id", "t", "--min-speed", repr(vmin), *VALIDATED)
    rc("estimate", *sum((["--drive", d] for d in drives), []), "--out", root / "estimate", "--grid-step", 0.1)
    return root, drives


@pytest.mark.parametrize("kind", BROKERS)
def test_validated_fleet_equals_estimate_on_the_segments_covered_whole(world, tmp_path, kind):
    import shutil

    root, drives = world
    fleet = tmp_path / "fleet"
    shutil.copytree(root / "fleet", fleet)
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    broker = None
    if kind == "amqtt":
        serve = start_serve(fleet, tmp_path / "s.sqlite", tmp_path / "serve.log", listen=port,
                            extra=("--round-timeout", 30))
    else:
        broker = start_mosquitto(fleet, port, tmp_path / "mosq", tmp_path / "broker.log")
        serve = start_serve(fleet, tmp_path / "s.sqlite", tmp_path / "serve.log", broker=url,
                            extra=("--round-timeout", 30))
    helpers = {name: start(PY, "-m", "roadcollab.cli.main", "helper", "--folder", fleet / name, "--broker", url,
                           log=tmp_path / f"{name}.log") for name in ("helper", "helper-c")}
    try:
        out = rc("fleet", "--fleet", fleet, *sum((["--drive", d] for d in drives), []), "--broker", url,
                 "--timeout", 400, timeout=600)
    finally:
        for name, helper in helpers.items():
            assert stop(helper) == 0, (tmp_path / f"{name}.log").read_text()
        assert stop(serve) == 0, (tmp_path / "serve.log").read_text()
        if broker is not None:
            stop(broker)
    assert "4 of 4 vehicles done" in out.stdout, out.stdout
    st = ServiceStore(tmp_path / "s.sqlite")
    try:
        assert all(d.startswith(b"RCSEAL1\x00") for _, _, d, _ in st.contributions())
        rounds = st.rounds()
    finally:
        st.close()
    finished = sorted(r["segment"] for r in rounds if r["phase"] == "finished")
    assert finished and all(sorted(r["used"]) == ["v1", "v2", "v3", "v4"] for r in rounds), rounds
    for name in ("helper", "helper-c"):
        with sqlite3.connect(fleet / name / "releases.sqlite") as db:
            assert db.execute("SELECT COUNT(*) FROM prio_releases").fetchone()[0] == 3 * len(finished)
    rc("export", "--store", tmp_path / "s.sqlite", "--out", tmp_path / "x")
    hv, v = read_csv(tmp_path / "x" / "final_estimate.csv")
    he, e = read_csv(root / "estimate" / "final_estimate.csv")
    pos_v, pos_e = v[:, hv.index("position_m")], e[:, he.index("position_m")]
    idx = np.searchsorted(pos_e, pos_v)
    assert np.allclose(pos_e[idx], pos_v)
    cov = v[:, hv.index("coverage")]
    assert set(np.unique(cov[cov > 0])) == {4}          # every estimated point from the 4 vehicles' session
    whole = cov == 4
    assert whole.sum() >= 0.6 * np.sum(e[:, he.index("coverage")] == 4)
    for track in ("left", "right"):
        got = v[whole, hv.index(f"elevation_fused_{track}")]
        ref = e[idx[whole], he.index(f"elevation_fused_{track}")]
        assert np.max(np.abs(got - ref)) < 4 * 2.0 ** -12, np.max(np.abs(got - ref))
