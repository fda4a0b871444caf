"""Scale of the networked fleet: N vehicle agents against one ``roadcollab serve`` and one broker.

    .venv/bin/python tools/net_scale.py --vehicles 10 30 100 --procs 4 --broker mosquitto

Agents are threads (one paho client each) in ``--procs`` worker processes; every agent is a
:class:`~roadcollab.network.agent.VehicleAgent` with its own enrolled identity and login. The road is the
measured profile (about 530 m) cut into 10 m segments (about 50); the drives are 4 simulated passes at 12,
15, 18 and 13-17 m/s, dealt round-robin to the agents (the service treats every agent as its own vehicle).
All agents start at once. Measured per fleet size:

* vehicle-segments per second at the service: contributions applied / (last - first apply time);
* latency from an agent publishing a segment's contribution to that segment's fused sums in the store
  (the store's apply time; one clock, one machine): median and 95th percentile;
* bytes on the wire per vehicle-segment (MQTT topic + payload, both directions, counted by the clients);
* memory per agent: (peak RSS of a worker - its RSS before its agents start) / agents in it.

With ``--aggregation secure`` the fleet is enrolled for secure aggregation (rounds of ``--round-size``,
``k = t = round size``): every agent also takes part in its segments' rounds, and the latency runs from
publishing a contribution to the store's close of the round that holds its input (``rounds.closed_s``).

Prints a Markdown table (``docs/network.md`` holds the measured one).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import resource
import shutil
import sqlite3
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def _worker(fleet: str, url: str, jobs: list, drives: list, out: str, secure: bool = False) -> None:
    """Run the agents ``jobs`` = [(vid, drive index)] as threads; write their publish times and bytes."""
    from roadcollab.io.drives import load_drive
    from roadcollab.network.agent import VehicleAgent
    from roadcollab.network.engine import VehicleEngine
    from roadcollab.network.fleetdir import load_aggregation, load_login, load_plan
    from roadcollab.network.relaykey import RelayKey
    from roadcollab.network.secround_agent import RoundAgent
    from roadcollab.privacy.secagg_store import SessionLedger
    from roadcollab.network.mqtt_client import MqttClient
    from roadcollab.network.mqtt_run import run_vehicle
    from roadcollab.wire.identity import FleetTrust, VehicleIdentity

    plan = load_plan(fleet)
    engines = {k: VehicleEngine(load_drive(d), plan, index=k) for k, d in enumerate(drives)}
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    results = {}

    class Timed:
        """A client wrapper recording when each segment's contribution was first published."""

        def __init__(self, c):
            self.c, self.t = c, {}

        def __getattr__(self, k):
            return getattr(self.c, k)

        def publish(self, topic, payload, retain=False):
            if "/seg/" in topic:
                self.t.setdefault(int(topic.rsplit("/", 1)[1]), time.time())
            self.c.publish(topic, payload, retain)

    def run(vid, k):
        folder = Path(fleet) / "vehicles" / vid
        ident, trust = VehicleIdentity.load(folder), FleetTrust.load(folder / "trust.toml")
        kw = {}
        if secure:
            kw = {"rounds": RoundAgent(ident, trust, load_aggregation(fleet).spec, SessionLedger(),
                                       f"rc/{plan.fleet_id}", {}), "relay_key": RelayKey.load(folder / "relay.key")}
        agent = VehicleAgent(engines[k], ident, trust, **kw)
        c = Timed(MqttClient(url, load_login(folder / "broker.toml"), f"scale-{vid}").connect(timeout=120))
        ok = run_vehicle(agent, c, timeout=600)
        c.close()
        results[vid] = {"ok": ok, "published": c.t, "bytes_out": c.c.bytes_out, "bytes_in": c.c.bytes_in,
                        "segments": len(agent.segments)}

    threads = [threading.Thread(target=run, args=j) for j in jobs]
    for t in threads:
        t.start()
    for t in threads:
        t.join(900)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    Path(out).write_text(json.dumps({"agents": results, "rss_base_kb": base, "rss_peak_kb": peak}))


def measure(n: int, procs: int, broker: str, drives: list, root: Path, vmin: float, round_size: int = 0,
            services: int = 1) -> dict:
    from netkit import free_port, rc, start_amqtt, start_mosquitto, start_serve, stop

    fleet = root / f"fleet{n}"
    sec = ("--aggregation", "secure", "--min-inputs", round_size, "--round-size", round_size) if round_size else ()
    rc("enroll", "--fleet", fleet, "--vehicles", n, "--fleet-id", "s", "--min-speed", repr(vmin),
       "--segment-length", 10, *sec)
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    b = (start_amqtt(fleet, port, root / f"b{n}.log") if broker == "amqtt"
         else start_mosquitto(fleet, port, root / f"m{n}", root / f"b{n}.log"))
    store = root / f"s{n}.sqlite"
    serves = [start_serve(fleet, store, root / f"serve{n}-{k}.log", broker=url, shared=services > 1)
              for k in range(services)]
    jobs = [[] for _ in range(procs)]
    for i in range(n):
        jobs[i % procs].append((f"v{i + 1}", i % len(drives)))
    ctx = mp.get_context("spawn")
    outs = [root / f"w{n}-{p}.json" for p in range(procs)]
    t0 = time.time()
    ws = [ctx.Process(target=_worker, args=(str(fleet), url, jobs[p], drives, str(outs[p]), bool(round_size)))
          for p in range(procs) if jobs[p]]
    for w in ws:
        w.start()
    for w in ws:
        w.join(1200)
    wall = time.time() - t0
    time.sleep(1.0)
    for serve in serves:
        stop(serve)
    stop(b)
    with sqlite3.connect(store) as db:
        applied = {(v, s): t for v, s, t in db.execute("SELECT vid, segment, received_s FROM contributions")}
        if round_size:    # a vehicle's input is in the fused sums when the round that used it closed
            applied = {}
            for s, used, closed in db.execute("SELECT segment, used, closed_s FROM rounds WHERE phase = 'finished'"):
                for v in json.loads(used):
                    applied[(v, s)] = closed
    agents, mem = {}, []
    for p, o in enumerate(outs):
        if not o.exists():
            continue
        w = json.loads(o.read_text())
        agents.update(w["agents"])
        if jobs[p]:
            mem.append((w["rss_peak_kb"] - w["rss_base_kb"]) / len(jobs[p]))
    lat = sorted(applied[(v, int(s))] - t for v, a in agents.items() for s, t in a["published"].items()
                 if (v, int(s)) in applied)
    times = sorted(applied.values())
    vs = len(applied)
    return {"vehicles": n, "done": sum(a["ok"] for a in agents.values()), "vehicle_segments": vs,
            "segments": len({s for _, s in applied}), "wall_s": wall,
            "vs_per_s": vs / max(times[-1] - times[0], 1e-9),
            "latency_median_s": statistics.median(lat), "latency_p95_s": lat[int(0.95 * (len(lat) - 1))],
            "bytes_per_vs": sum(a["bytes_out"] + a["bytes_in"] for a in agents.values()) / vs,
            "bytes_out_per_vs": sum(a["bytes_out"] for a in agents.values()) / vs,
            "mem_per_agent_mb": statistics.mean(mem) / 1024}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--vehicles", type=int, nargs="+", default=[10, 30, 100])
    p.add_argument("--procs", type=int, default=4)
    p.add_argument("--broker", choices=["mosquitto", "amqtt"], default="mosquitto")
    p.add_argument("--keep", action="store_true", help="keep the temporary folder")
    p.add_argument("--aggregation", choices=["clear", "secure"], default="clear")
    p.add_argument("--round-size", type=int, default=5, help="secure: vehicles per round (k = t = this)")
    p.add_argument("--services", type=int, default=1, help="serve --shared instances on one store (SQLite)")
    args = p.parse_args(argv)
    from netkit import write_drives
    from roadcollab.io.drives import load_drives

    root = Path(tempfile.mkdtemp(prefix="rc-scale-"))
    try:
        drives, _ = write_drives(root / "drives")
        vmin = min(float(d.speeds().min()) for d in load_drives(drives))
        rs = args.round_size if args.aggregation == "secure" else 0
        rows = [measure(n, args.procs, args.broker, drives, root, vmin, rs, args.services) for n in args.vehicles]
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    print("| agents | done | vehicle-segments | vehicle-segments/s at the service | latency median (s) | "
          "latency p95 (s) | bytes/vehicle-segment (both ways) | bytes/vehicle-segment sent | MB per agent | "
          "wall (s) |\n|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['vehicles']} | {r['done']} | {r['vehicle_segments']} | {r['vs_per_s']:.1f} | "
              f"{r['latency_median_s']:.3f} | {r['latency_p95_s']:.3f} | {r['bytes_per_vs']:.0f} | "
              f"{r['bytes_out_per_vs']:.0f} | {r['mem_per_agent_mb']:.2f} | {r['wall_s']:.1f} |")
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
