"""CPU time per party of a validated fleet (enroll --aggregation validated), over the in-memory transport.

The four mixed-speed drives of the tests (tests/conftest.py), one segment per 100 m; the service (leader A),
each helper (B, C) and every vehicle timed apart (their message handlers, in this one process).
Usage: .venv/bin/python tools/validated_cost.py [GRID_STEP_M] [PHASES] [AGGREGATORS]
(defaults 0.05, 0: the schedule, and 3)
"""
import sys
import time
from collections import defaultdict

import numpy as np

from roadcollab.experiments.drives.mixed_fleet import MIXED_SPEEDS, simulate_drive
from roadcollab.io.profiles import measured_road
from roadcollab.models.vehicle import FleetSpec, sample_fleet
from roadcollab.network import memory
from roadcollab.network.aggregation import AggregationPolicy, validated_params
from roadcollab.network.plan import RoadPlan
from roadcollab.network.results import results_from_store
from roadcollab.network.service import Service

step = float(sys.argv[1]) if len(sys.argv) > 1 else 0.05
phases = int(sys.argv[2]) if len(sys.argv) > 2 else 0
aggregators = int(sys.argv[3]) if len(sys.argv) > 3 else 3
road, fleet = measured_road(rng=1), sample_fleet(4, FleetSpec(), rng=2)
drives = [simulate_drive(road, fleet[j], sp, start=5.0 + 2 * j, rng=10 + j) for j, sp in enumerate(MIXED_SPEEDS)]
plan = RoadPlan(fleet_id="t", spacing=step, min_speed=min(float(d.speeds().min()) for d in drives))
policy = AggregationPolicy(mode="validated", round_size=4, min_inputs=3, threshold=3, clip_m=0.2, phases=phases,
                           aggregators=aggregators)
params = validated_params(plan, policy)
cpu: dict = defaultdict(float)


def timed(label, fn):
    def g(*a, **k):
        t0 = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            cpu[label] += time.process_time() - t0
    return g


orig_service_handle, orig_parties, orig_agent = Service.handle, memory._validated_parties, memory._round_agent
Service.handle = lambda self, t, p: timed("service (A)", orig_service_handle)(self, t, p)


def parties(*a):
    rounds, helpers = orig_parties(*a)
    for h in helpers:
        h.handle = timed(f"helper {h.keys.party}", h.handle)
    return rounds, helpers


def agent(ident, *a):
    rounds = orig_agent(ident, *a)
    rounds.on_message = timed(f"vehicle {ident.vehicle_id}", rounds.on_message)
    return rounds


memory._validated_parties, memory._round_agent = parties, agent
t0 = time.perf_counter()
clear = results_from_store(memory.run_in_memory(drives, plan)[0])
t_clear = time.perf_counter() - t0
t0 = time.perf_counter()
store, broker = memory.run_in_memory(drives, plan, aggregation=policy)
wall = time.perf_counter() - t0
rounds = [r for r in store.rounds() if r["phase"] == "finished"]
res = results_from_store(store)
idx = np.searchsorted(clear.position, res.position)
ok = np.isfinite(res.fused[:, 0])
print(f"grid {step} m, {aggregators} aggregators: {plan.points_per_segment} points per segment, "
      f"L = {params.wide.length}, K = {params.phases}; "
      f"{len(rounds)} sessions finished, {broker.bytes_published / 1e6:.1f} MB published; wall {wall:.1f} s "
      f"(the clear run {t_clear:.1f} s)")
print(f"largest difference to the clear mean: {np.max(np.abs(res.fused[ok] - clear.fused[idx][ok])):.3g} m")
for label, s in sorted(cpu.items()):
    print(f"  {label:20s} {s:7.2f} s CPU, {s / max(1, len(rounds)):6.2f} s per session")
