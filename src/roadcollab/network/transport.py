"""The transport interface and the in-memory transport.

A transport moves ``(topic, payload)`` between clients with MQTT's semantics where the engine relies on
them: topic filters with ``+`` and ``#``, a retained message per topic delivered on subscription, and
delivery in publication order. :class:`MemoryBroker` does this inside one process (``estimate``-style
runs and tests); :mod:`roadcollab.network.mqtt_client` does it over a real broker.
"""

from __future__ import annotations

from collections import deque
from typing import Protocol

__all__ = ["Transport", "MemoryBroker", "MemoryClient", "topic_matches"]


class Transport(Protocol):
    """What the service and vehicle loops need from a transport."""

    def subscribe(self, topic_filter: str) -> None: ...

    def publish(self, topic: str, payload: bytes, retain: bool = False) -> None: ...

    def receive(self, timeout: float) -> tuple[str, bytes] | None: ...


def topic_matches(topic_filter: str, topic: str) -> bool:
    """MQTT topic-filter matching (``+`` one level, ``#`` the rest).

    Parameters
    ----------
    topic_filter : str
    topic : str
    """
    f, t = topic_filter.split("/"), topic.split("/")
    for i, part in enumerate(f):
        if part == "#":
            return True
        if i >= len(t) or (part != "+" and part != t[i]):
            return False
    return len(f) == len(t)


class MemoryBroker:
    """An in-process broker: subscriptions, retained messages, per-client queues."""

    def __init__(self) -> None:
        self.retained: dict[str, bytes] = {}
        self.clients: list[MemoryClient] = []
        self.bytes_published = 0

    def client(self) -> "MemoryClient":
        c = MemoryClient(self)
        self.clients.append(c)
        return c

    def _publish(self, topic: str, payload: bytes, retain: bool) -> None:
        self.bytes_published += len(topic) + len(payload)
        if retain:
            self.retained[topic] = bytes(payload)
        for c in self.clients:
            if any(topic_matches(f, topic) for f in c.filters):
                c.queue.append((topic, bytes(payload)))


class MemoryClient:
    """One client of a :class:`MemoryBroker` (a :class:`Transport`)."""

    def __init__(self, broker: MemoryBroker) -> None:
        self.broker = broker
        self.filters: list[str] = []
        self.queue: deque[tuple[str, bytes]] = deque()

    def subscribe(self, topic_filter: str) -> None:
        self.filters.append(topic_filter)
        for t, p in self.broker.retained.items():
            if topic_matches(topic_filter, t):
                self.queue.append((t, p))

    def publish(self, topic: str, payload: bytes, retain: bool = False) -> None:
        self.broker._publish(topic, payload, retain)

    def receive(self, timeout: float = 0.0) -> tuple[str, bytes] | None:
        return self.queue.popleft() if self.queue else None
