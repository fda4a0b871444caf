"""The engine over the in-memory transport: the service and every vehicle in one process.

The same :class:`~roadcollab.network.service.Service` and
:class:`~roadcollab.network.agent.VehicleAgent` as the networked run, with a
:class:`~roadcollab.network.transport.MemoryBroker` in place of MQTT; vehicles drive one after another
(as ``estimate`` takes the drives), each to its last acknowledgement.
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import ParameterError
from ..experiments.config import ExperimentConfig
from ..experiments.distance_maps import distance_grid
from ..experiments.fleet_estimation import FleetEstimates
from ..wire.identity import FleetAuthority, VehicleIdentity
from .agent import VehicleAgent
from .engine import VehicleEngine
from .fleetroad import align_to_waiting
from .plan import RoadPlan
from .results import results_from_store
from .service import Service
from .store import ServiceStore
from .transport import MemoryBroker

__all__ = ["run_in_memory", "estimate_fleet_in_memory"]


def _pump(service: Service, svc, agent: VehicleAgent, car, limit: int) -> None:
    """Deliver queued messages both ways until neither side has any (at most ``limit`` rounds)."""
    for _ in range(limit):
        moved = False
        while (m := svc.receive(0.0)) is not None:
            for p in service.handle(*m):
                svc.publish(p.topic, p.payload, p.retain)
            moved = True
        while (m := car.receive(0.0)) is not None:
            for p in agent.on_message(*m):
                car.publish(p.topic, p.payload, p.retain)
            moved = True
        if not moved:
            return
    raise ParameterError(f"the in-memory run did not settle within {limit} rounds")


def run_in_memory(drives, plan: RoadPlan, *, store: ServiceStore | None = None, authority: FleetAuthority | None = None,
                  on_fused=None, road=None) -> tuple[ServiceStore, MemoryBroker]:
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
    road : FleetRoad, optional
        The fleet's road (``plan.road_id``): each vehicle places its GPS drive on it first
        (:meth:`~roadcollab.network.fleetroad.FleetRoad.place`) and aligns it to the waiting messages
        (:func:`~roadcollab.network.fleetroad.align_to_waiting`), as ``roadcollab vehicle`` does.

    Returns
    -------
    ServiceStore
        The service's results (read them with :func:`roadcollab.network.results.results_from_store`).
    MemoryBroker
        The transport (``bytes_published``).
    """
    store = ServiceStore(":memory:", plan) if store is None else store
    authority = FleetAuthority.generate(plan.fleet_id) if authority is None else authority
    service = Service(store, authority.trust(), on_fused=on_fused)
    broker = MemoryBroker()
    svc = broker.client()
    svc.subscribe(service.topics.from_vehicles)
    for j, d in enumerate(drives):
        extra = realign = None
        if road is not None:
            d, extra = road.place(d)
            realign = functools.partial(align_to_waiting, index=j)
        agent = VehicleAgent(VehicleEngine(d, plan, index=j), VehicleIdentity.enroll(authority, f"v{j + 1}"),
                             authority.trust(), hello_extra=extra, realign=realign)
        car = broker.client()
        for f in agent.subscriptions:
            car.subscribe(f)
        for p in agent.start():
            car.publish(p.topic, p.payload, p.retain)
        _pump(service, svc, agent, car, limit=100)
        if not agent.done:
            raise ParameterError(f"vehicle v{j + 1}: segments left unacknowledged {sorted(agent.pending)}")
    return store, broker


def estimate_fleet_in_memory(drives, *, spacing: float = 0.05, gamma: float | None = None,
                             band_low_hz: float | None = None) -> FleetEstimates:
    """:func:`~roadcollab.experiments.fleet_estimation.estimate_fleet` (unaligned, no fleet prior) through
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
    store, _ = run_in_memory(drives, plan)
    r = results_from_store(store)
    V = len(drives)
    return FleetEstimates(drives=list(drives), position=r.position, spacing=float(spacing), elevation=r.elevation,
                          offsets=np.zeros(V), offset_peaks=np.full(V, np.nan), band_low_per_m=plan.band_low_per_m,
                          band_low_hz=float(band_low_hz), gamma=float(gamma), aligned=False)
