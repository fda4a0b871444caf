"""The engine over the in-memory transport: the service and every vehicle in one process.

The same :class:`~roadcollab.network.service.Service` and
:class:`~roadcollab.network.agent.VehicleAgent` as the networked run, with a
:class:`~roadcollab.network.transport.MemoryBroker` in place of MQTT; vehicles drive one after another
(as ``estimate`` takes the drives), each to its last acknowledgement. Under secure aggregation every
vehicle stays on the transport until its rounds close (the rounds need their rosters online together);
a phase times out only when no message moves (``offline`` vehicles receive nothing: killed processes).
"""

from __future__ import annotations


import numpy as np

from ..errors import ParameterError
from ..experiments.config import ExperimentConfig
from ..experiments.drives.distance_maps import distance_grid
from ..experiments.drives.fleet_estimation import GUARD_ROAD_DEFAULT, FleetEstimates
from ..wire.identity import FleetAuthority, VehicleIdentity
from ..privacy.secagg_store import ReleaseLog, SessionLedger
from .agent import VehicleAgent
from .aggregation import AggregationPolicy, validated_params
from .fleetlanes import placed_engine
from .plan import RoadPlan
from .prioagent import PrioAgent
from .priohelper import PrioHelperService
from .priowire import AggregatorKeys
from .relaykey import RelayKey
from .results import results_from_store
from .rounds import SecureRounds
from .secround_agent import RoundAgent
from .service import Service
from .store import ServiceStore
from .transport import MemoryBroker
from .validated_rounds import ValidatedRounds

__all__ = ["run_in_memory", "estimate_fleet_in_memory"]


class _Handler:
    """A party on the transport that only answers messages (a helper)."""

    def __init__(self, on_message) -> None:
        self.on_message = on_message


def _pump_all(service: Service, svc, cars: dict, agents: dict, offline, limit: int) -> None:
    """Deliver until nothing moves, over every vehicle (``offline`` ones drain their queue unread)."""
    for _ in range(limit):
        moved = False
        while (m := svc.receive(0.0)) is not None:
            for p in service.handle(*m):
                svc.publish(p.topic, p.payload, p.retain)
            moved = True
        for vid, car in cars.items():
            while (m := car.receive(0.0)) is not None:
                moved = True
                if vid in offline:
                    continue
                for p in agents[vid].on_message(*m):
                    car.publish(p.topic, p.payload, p.retain)
        if not moved:
            return
    raise ParameterError(f"the in-memory run did not settle within {limit} rounds")


def run_in_memory(drives, plan: RoadPlan, *, store: ServiceStore | None = None, authority: FleetAuthority | None = None,
                  on_fused=None, road=None, aggregation: AggregationPolicy | None = None, offline=(),
                  timeouts: int = 50, guard: str | None = GUARD_ROAD_DEFAULT) -> tuple[ServiceStore, MemoryBroker]:
    """Every drive through the service over the in-memory transport, in order.

    Parameters
    ----------
    drives : list of Drive
        In driving order (vehicle ``v<k>`` drives the ``k``-th).
    plan : RoadPlan
    store : ServiceStore, optional
        Default: a new in-memory store.
    authority : FleetAuthority, optional
        Default: a throwaway authority (the identities never leave the process).
    on_fused : callable, optional
        The service's hook (:class:`~roadcollab.network.service.Service`), e.g. a ``RoadSync``.
    road : FleetRoad or NetworkLanes, optional
        The fleet's road (``plan.road_id``): each vehicle places its GPS drive on it first
        (:meth:`~roadcollab.network.fleetroad.FleetRoad.place`) and aligns it to the waiting messages
        (:func:`~roadcollab.network.fleetroad.align_to_waiting`), as ``roadcollab vehicle`` does; or
        every road of the fleet's network (plan ``road_id`` ``*``): each vehicle on every lane it passed
        (:mod:`roadcollab.network.fleetlanes`).
    aggregation : AggregationPolicy, optional
        Default: in the clear.
    offline : iterable of str
        Secure aggregation: vehicles that vanish once they have contributed (they answer no round message).
    timeouts : int
        Secure aggregation: service timeouts at most (each closes every open phase with what arrived).
    guard : {"class", "own"} or None
        Every vehicle's receiver guard road prior (:class:`~roadcollab.network.engine.VehicleEngine`); None:
        unguarded (the opt-out).

    Returns
    -------
    ServiceStore
        The service's results (read them with :func:`roadcollab.network.results.results_from_store`).
    MemoryBroker
        The transport (``bytes_published``).
    """
    store = ServiceStore(":memory:", plan) if store is None else store
    authority = FleetAuthority.generate(plan.fleet_id) if authority is None else authority
    trust = authority.trust()
    rounds, helpers = None, []
    if aggregation is not None and aggregation.validated:
        rounds, helpers = _validated_parties(store, authority, aggregation)
    elif aggregation is not None and aggregation.secure:
        rounds = SecureRounds(store, trust, aggregation, f"rc/{plan.fleet_id}", phase_timeout_s=0.0,
                              round_wait_s=float("inf"))
    service = Service(store, trust, on_fused=on_fused, rounds=rounds)
    broker = MemoryBroker()
    svc = broker.client()
    for f in service.subscriptions:
        svc.subscribe(f)
    if rounds is not None:
        return _run_secure(drives, plan, store, authority, service, broker, svc, aggregation, set(offline), timeouts,
                           road, guard, helpers)
    for j, d in enumerate(drives):
        engine, extra, realign = placed_engine(d, plan, road, j, guard=guard)
        agent = VehicleAgent(engine, VehicleIdentity.enroll(authority, f"v{j + 1}"),
                             authority.trust(), hello_extra=extra, realign=realign)
        car = broker.client()
        for f in agent.subscriptions:
            car.subscribe(f)
        for p in agent.start():
            car.publish(p.topic, p.payload, p.retain)
        _pump_all(service, svc, {agent.vid: car}, {agent.vid: agent}, set(), limit=100)
        if not agent.done:
            raise ParameterError(f"vehicle v{j + 1}: segments left unacknowledged {sorted(agent.pending)}")
    return store, broker


def _validated_parties(store: ServiceStore, authority: FleetAuthority, policy: AggregationPolicy):
    """The service's :class:`ValidatedRounds` and the helpers (other operators, here in the same process)."""
    prefix, trust = f"rc/{store.plan.fleet_id}", authority.trust()
    params = validated_params(store.plan, policy)
    ka = AggregatorKeys(VehicleIdentity.enroll(authority, params.leader_id), RelayKey.generate())
    kh = {h: AggregatorKeys(VehicleIdentity.enroll(authority, h), RelayKey.generate()) for h in params.helper_ids}
    rounds = ValidatedRounds(store, trust, policy, prefix, keys=ka, release_log=ReleaseLog(),
                             helper_adverts={h: k.advert(prefix) for h, k in kh.items()}, phase_timeout_s=0.0,
                             round_wait_s=float("inf"))
    return rounds, [PrioHelperService(prefix, params, trust, k, ReleaseLog()) for k in kh.values()]


def _round_agent(ident: VehicleIdentity, trust, policy: AggregationPolicy, prefix: str, plan: RoadPlan):
    """A vehicle's side of the fleet's rounds (it knows its inputs to them and its hello fields)."""
    if policy.validated:
        return PrioAgent(ident, trust, validated_params(plan, policy), SessionLedger(), prefix, {})
    return RoundAgent(ident, trust, policy.spec, SessionLedger(), prefix, {})


def _run_secure(drives, plan, store, authority, service, broker, svc, policy, offline, timeouts, road=None,
                guard=GUARD_ROAD_DEFAULT, helpers=()):
    trust = authority.trust()
    relay = RelayKey.generate()
    agents, cars = {}, {}
    parties: dict = {}
    for helper in helpers:       # the other aggregators: one more party each on the transport
        hc = broker.client()
        for filt in helper.subscriptions:
            hc.subscribe(filt)
        cars[helper.keys.party], parties[helper.keys.party] = hc, _Handler(helper.handle)
    for j, d in enumerate(drives):
        ident = VehicleIdentity.enroll(authority, f"v{j + 1}")
        rounds = _round_agent(ident, trust, policy, f"rc/{plan.fleet_id}", plan)
        engine, extra, realign = placed_engine(d, plan, road, j, guard=guard)
        agent = VehicleAgent(engine, ident, trust, rounds=rounds, relay_key=relay, hello_extra=extra,
                             realign=realign)
        car = broker.client()
        for f in agent.subscriptions:
            car.subscribe(f)
        agents[agent.vid], cars[agent.vid] = agent, car
        parties[agent.vid] = agent
        for p in agent.start():
            car.publish(p.topic, p.payload, p.retain)
        _pump_all(service, svc, cars, parties, set(), limit=1000)
        if not agent.contributed:
            raise ParameterError(f"vehicle {agent.vid}: segments left unacknowledged {sorted(agent.pending)}")
    # Every vehicle has driven: a segment with fewer than round_size free vehicles opens with those left
    # (at least k) at the next timeout, as a service whose round_wait_s has passed.
    service.rounds.round_wait_s = 0.0
    for _ in range(timeouts):   # rounds: each pass delivers everything, then one service timeout
        _pump_all(service, svc, cars, parties, offline, limit=1000)
        if all(a.done for v, a in agents.items() if v not in offline) and not service.rounds.active:
            break
        for p in service.tick():
            svc.publish(p.topic, p.payload, p.retain)
    return store, broker


def estimate_fleet_in_memory(drives, *, spacing: float = 0.05, gamma: float | None = None,
                             band_low_hz: float | None = None, guard: str | None = GUARD_ROAD_DEFAULT
                             ) -> FleetEstimates:
    """:func:`~roadcollab.experiments.drives.fleet_estimation.estimate_fleet` (unaligned, no fleet prior) through
    the service and the vehicles over the in-memory transport: what ``roadcollab estimate`` runs.

    The plan takes the band edge from the drives' slowest speed, as ``estimate_fleet`` does, and 100 m
    segments (rounded to whole grid steps); ``tests/test_network_engine.py`` checks that the result is
    ``estimate_fleet``'s bit for bit.

    Parameters
    ----------
    drives : list of Drive
        In driving order.
    spacing : float
        Distance grid step, m.
    gamma, band_low_hz : float, optional
        Observer parameter and band edge (Hz); default the ExperimentConfig defaults.
    guard : {"class", "own"} or None
        Every vehicle's receiver guard road prior, as ``estimate_fleet(..., guard=)``; None: unguarded.

    Returns
    -------
    FleetEstimates
        ``aligned=False``, zero offsets.
    """
    if not drives:
        raise ParameterError("drives must be a non-empty list of Drive (see load_drives)")
    base = ExperimentConfig()
    gamma = base.gamma if gamma is None else gamma
    band_low_hz = base.band_low_hz if band_low_hz is None else band_low_hz
    # The same grid and its checks as estimate_fleet (e.g. drives covering fewer than 16 grid steps).
    distance_grid([d.positions[0] for d in drives], [d.positions[-1] for d in drives], spacing)
    vmin = min(float(d.speeds().min()) for d in drives)
    plan = RoadPlan(fleet_id="estimate", spacing=spacing, segment_length=spacing * max(16, round(100.0 / spacing)),
                    min_speed=vmin, band_low_hz=band_low_hz, gamma=gamma)
    store, _ = run_in_memory(drives, plan, guard=guard)
    r = results_from_store(store)
    V = len(drives)
    return FleetEstimates(drives=list(drives), position=r.position, spacing=float(spacing), elevation=r.elevation,
                          offsets=np.zeros(V), offset_peaks=np.full(V, np.nan), band_low_per_m=plan.band_low_per_m,
                          band_low_hz=float(band_low_hz), gamma=float(gamma), aligned=False,
                          receiver_guard=guard or "none")
