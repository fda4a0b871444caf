"""The service's and a vehicle's loops over a transport (MQTT in practice; any :class:`Transport`).

Both loops are bounded: the service runs until ``stop`` is set (SIGINT/SIGTERM), a vehicle until all
its segments are acknowledged or ``timeout`` seconds pass. A vehicle sends again what is not yet
acknowledged after ``resend_s`` seconds without progress (backing off to 60 s) and after every reconnection, so a message
lost with a killed service or broker is sent again; the service applies each once.
"""

from __future__ import annotations

import functools
import sys
import threading
import time
from typing import Callable, Protocol

from .agent import VehicleAgent
from .service import Publish

__all__ = ["run_service", "run_vehicle", "Party"]


class Party(Protocol):
    """What :func:`run_service` runs: the :class:`~roadcollab.network.service.Service`, or the helper
    (:class:`~roadcollab.network.priohelper.HelperParty`)."""

    def on_connect(self) -> list[Publish]: ...

    def tick(self) -> list[Publish]: ...

    def handle(self, topic: str, payload: bytes) -> list[Publish]: ...


def run_service(service: Party, client, stop: threading.Event, republish: threading.Event, *,
                log: Callable[[str], None] | None = None, idle_s: float = 0.2) -> int:
    """Serve until ``stop`` is set; the number of messages handled.

    Parameters
    ----------
    log : callable, optional
        One line per event.
    idle_s : float
        Receive timeout, s (how often ``stop`` is checked).
    service : Service or HelperParty
    client : Transport
        Already subscribed to the vehicle topics.
    stop, republish : threading.Event
        ``republish`` is set by the client after every (re)connection: the retained messages are sent
        again then.
    """
    handled = 0
    next_tick = time.monotonic() + 1.0
    while not stop.is_set():
        if republish.is_set():
            republish.clear()
            for p in service.on_connect():
                client.publish(p.topic, p.payload, p.retain)
        if time.monotonic() >= next_tick:       # timeouts of secure-aggregation rounds
            next_tick = time.monotonic() + 1.0
            for p in _guarded(service.tick, "a timer tick", log):
                client.publish(p.topic, p.payload, p.retain)
        m = client.receive(idle_s)
        if m is None:
            continue
        handled += 1
        topic, payload = m
        for p in _guarded(functools.partial(service.handle, topic, payload), f"a message on {topic[:200]!r}", log):
            client.publish(p.topic, p.payload, p.retain)
    return handled


def _guarded(step: Callable[[], list[Publish]], what: str, log: Callable[[str], None] | None) -> list[Publish]:
    """``step()``; an exception that escapes it (a defect: every refusal is recorded inside) is one line on
    stderr (or ``log``) and the message is dropped, so that one message cannot stop the service."""
    try:
        return step()
    except Exception as err:     # noqa: BLE001 - the service's last line of defence, reported
        line = f"error: {what} raised {type(err).__name__}: {str(err)[:300]} (dropped; the service goes on)"
        (log or (lambda s: print(s, file=sys.stderr, flush=True)))(line)
        return []


def run_vehicle(agent: VehicleAgent, client, *, timeout: float, resend_s: float = 15.0,
                reconnected: threading.Event | None = None, on_contributed: Callable[[], None] | None = None) -> bool:
    """Run the vehicle's protocol to its last acknowledgement; True if done within ``timeout`` s.

    Parameters
    ----------
    agent : VehicleAgent
    client : Transport
    timeout : float
        s.
    resend_s : float
        Resend what is unacknowledged after this long without progress, s; doubled after every resend
        without progress (at most 60 s), reset by progress and by a reconnection.
    reconnected : threading.Event, optional
        Set by the client on every reconnection (resend at once).
    on_contributed : callable, optional
        Called once when every segment is acknowledged (secure aggregation: the rounds may still run).
    """
    for f in agent.subscriptions:
        client.subscribe(f)
    for p in agent.start():
        client.publish(p.topic, p.payload, p.retain)
    end = time.monotonic() + timeout
    last, wait = time.monotonic(), resend_s
    while not agent.done and time.monotonic() < end:
        if reconnected is not None and reconnected.is_set():
            reconnected.clear()
            last, wait = 0.0, resend_s
        if time.monotonic() - last > wait:
            for p in agent.resend():
                client.publish(p.topic, p.payload, p.retain)
            # QoS 1 already delivers to the service's persistent session; these copies only cover a
            # message lost inside a killed service or a restarted in-memory broker. Back off while the
            # service makes no progress on this vehicle: at 100 agents a 3 s resend multiplied the bytes
            # sent per vehicle-segment by 5 (tools/net_scale.py) and buried the busy service in copies.
            last, wait = time.monotonic(), min(2 * wait, 60.0)
        m = client.receive(0.1)
        if m is None:
            continue
        before = (agent.started, len(agent.outcomes))
        topic, payload = m
        for p in _guarded(functools.partial(agent.on_message, topic, payload), f"a message on {topic[:200]!r}", None):
            client.publish(p.topic, p.payload, p.retain)
        if (agent.started, len(agent.outcomes)) != before:
            last, wait = time.monotonic(), resend_s
        if on_contributed is not None and agent.contributed:
            on_contributed()
            on_contributed = None
    return agent.done
