"""One ``fused_secagg_bounded`` row measured through the networked phased sessions (issue 20).

The fusion-poisoning study's ``secagg_bounded`` node computes what the phased protocol reveals (centred
clipping of :mod:`roadcollab.experiments.security.secagg_bounded`, no proofs). This script runs the same
run's honest session and one attacked session through the protocol as messages between the leader, the
two helpers and the ten vehicles (:mod:`roadcollab.network.prioround`, in-memory transport; the same code the
processes of ``python -m roadcollab.network.prio_mqtt`` run), with every proof made and checked, and
compares the result and the row's MSE ratio with the study node's.

Usage: ``python tools/networked_bounded_row.py [STRATEGY] [RUN]`` (default ``scale_10`` on run 0, seed 0).
Prints the largest difference of the revealed results and both ratios. Slow: every phase proves ``L =
13,504`` values per vehicle (minutes per session).
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from roadcollab.collaboration.guard import ReceiverGuard
from roadcollab.experiments.anomalies.config import AnomalyStudyConfig
from roadcollab.experiments.pipeline import FleetPipeline, fleet_and_run_seeds
from roadcollab.experiments.security import fusion_poisoning as fp
from roadcollab.experiments.security.secagg_bounded import BOUNDED_FINAL, ball_radius, bounded_inputs, centred_clipping
from roadcollab.experiments.seeds import SeedPlan, run_stream
from roadcollab.network.prioagent import PrioAgent, run_prio_session
from roadcollab.network.priohelper import PrioHelperService
from roadcollab.network.prioround import PrioLeader, PrioParams
from roadcollab.network.priowire import AggregatorKeys
from roadcollab.network.relaykey import RelayKey
from roadcollab.privacy.secagg_flp import ValidityEncoding
from roadcollab.privacy.secagg_phased import public_schedule, radius_schedule
from roadcollab.privacy.secagg_store import ReleaseLog, SessionLedger
from roadcollab.wire.identity import FleetAuthority, VehicleIdentity

PREFIX = "rc/study"


class RawAgent(PrioAgent):
    """A vehicle whose later phases use its raw vector, not its phase-1 input clipped into the box (the
    study node's attacker: ``raw_i - m`` scaled onto the ball)."""

    def __init__(self, *args, raw: np.ndarray, **kw) -> None:
        super().__init__(*args, **kw)
        self.raw = raw

    def _answer(self, key, k, h, blobs):
        if k > 1:
            self._u[key] = self.raw
        return super()._answer(key, k, h, blobs)


def networked(run, first, raw, phases, grow, attacker=None):
    box, wide = run.validity
    radii = radius_schedule(run.radius, phases, grow)
    tight = tuple(ValidityEncoding(np.full(wide.length, r), r * 2.0 ** -23, norm=r) for r in radii)
    params = PrioParams(wide, tight, min_inputs=len(first) // 2 + 1)
    auth = FleetAuthority.generate("study")
    trust = auth.trust()
    ka = AggregatorKeys(VehicleIdentity.enroll(auth, params.leader_id), RelayKey.generate())
    kh = [AggregatorKeys(VehicleIdentity.enroll(auth, h), RelayKey.generate()) for h in params.helper_ids]
    agents = {}
    for i, u in enumerate(raw):
        cls, kw = (RawAgent, {"raw": u}) if i == attacker else (PrioAgent, {})
        v = f"v{i + 1}"
        agents[v] = cls(VehicleIdentity.enroll(auth, v), trust, params, SessionLedger(), PREFIX, {0: u},
                        rng=np.random.default_rng(i), **kw)
    leader = PrioLeader(PREFIX, 0, 0, params, trust, ka, [k.advert(PREFIX) for k in kh], ReleaseLog())
    helpers = [PrioHelperService(PREFIX, params, trust, k, ReleaseLog()) for k in kh]
    broker = run_prio_session(leader, helpers, agents, list(agents))
    return leader, broker


def main(strategy: str = "scale_10", r: int = 0, seed: int = 0, malicious: int = 4) -> None:
    config = AnomalyStudyConfig()
    exp = config.experiment
    pipe = FleetPipeline(exp, fleet_and_run_seeds(exp, seed)[0])
    guard = ReceiverGuard(pipe.estimators[0], pipe.road_moment, exp.sensor_noise_std)
    box = fp.validity_box(pipe, guard)
    radius = ball_radius(fp.public_error(pipe, guard), exp.n_vehicles)
    phases, grow = public_schedule(2 * float(np.linalg.norm(box[1].bounds)) / exp.n_vehicles, radius, BOUNDED_FINAL)
    seeds = SeedPlan(seed).runs(r + 1)
    run = dataclasses.replace(fp._honest_run(pipe, seeds[r], config.road_spec(), guard), box=box, radius=radius,
                              schedule=(phases, grow))
    rng = np.random.default_rng(run_stream(seeds[r], "privacy"))
    honest = [run.message(z) for z in run.z]
    z_m, count, _ = fp._attack(strategy, run, malicious, rng)
    attacked = honest[:malicious] + [run.message(z_m, count)] + honest[malicious + 1:]
    print(f"L = {box[1].length}, K = {phases}, grow = {grow}, R = {radius:.4g}", flush=True)
    scores = {}
    for name, msgs, att in (("honest", honest, None), (strategy, attacked, malicious)):
        first, raw = bounded_inputs(run, msgs)
        m_ideal, _ = centred_clipping(first, raw, radius, phases, grow=grow)
        t = time.perf_counter()
        leader, broker = networked(run, first, raw, phases, grow, attacker=att)
        wall = time.perf_counter() - t
        if leader.result is None:
            print(f"{name}: session {leader.state}: {leader.events[-1:]}")
            return
        diff = float(np.max(np.abs(leader.result - m_ideal)))
        scores[name] = (fp._score(run, fp.through_guard(run, m_ideal, len(first))),
                        fp._score(run, fp.through_guard(run, leader.result, len(first))))
        print(f"{name}: {leader.state}, accepted {len(leader.accepted)}, max |m_net - m_study| = {diff:.3g} "
              f"(max |m| {float(np.max(np.abs(m_ideal))):.3g}), {wall:.0f} s, {broker.bytes_published / 1e6:.1f} MB",
              flush=True)
    (h_i, h_n), (a_i, a_n) = scores["honest"], scores[strategy]
    print(f"{strategy} ratio: study node {a_i / h_i:.4f}, networked {a_n / h_n:.4f}")


if __name__ == "__main__":
    main(*(sys.argv[1:2] or ["scale_10"]), *(int(a) for a in sys.argv[2:3]))
