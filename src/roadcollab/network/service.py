"""The roadside service's protocol: a state machine from received messages to store writes and replies.

It knows no transport: :meth:`Service.handle` takes one ``(topic, payload)`` and returns the messages
to publish; the MQTT loop (:mod:`roadcollab.network.mqtt_run`) and the in-memory run
(:mod:`roadcollab.network.memory`) drive it the same way. Every refusal is one event in the store with
its reason, and nothing a vehicle sends raises out of :meth:`Service.handle`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from ..errors import MessageError, ParameterError
from .fleetroad import check_hello
from ..wire.identity import FleetTrust
from .messages import Topics, decode_contribution, decode_json, encode_json, encode_waiting, open_from, \
    sealed_segment
from .store import ServiceStore

if TYPE_CHECKING:
    from .rounds import SecureRounds

__all__ = ["Publish", "Service", "encode_hello_ack", "decode_hello_ack"]


@dataclass(frozen=True)
class Publish:
    """One message to publish: ``topic``, ``payload`` (bytes), ``retain``."""

    topic: str
    payload: bytes
    retain: bool = False


def encode_hello_ack(done: list[int], waiting: dict[int, tuple[str, bytes]]) -> bytes:
    """The reply to a hello: the segments already applied and, per segment, the message waiting for it.

    Parameters
    ----------
    done : list of int
        Segments of this vehicle already applied.
    waiting : dict
        ``{segment: (sender, envelope)}``.

    Wire form: ``u32 len header | header JSON | envelopes``, the header listing
    ``[segment, sender, offset, length]`` of each envelope in the blob that follows.
    """
    blobs, index, off = [], [], 0
    for s, (vid, env) in sorted(waiting.items()):
        index.append([s, vid, off, len(env)])
        blobs.append(env)
        off += len(env)
    head = encode_json({"type": "hello", "done": done, "waiting": index})
    return struct.pack("<I", len(head)) + head + b"".join(blobs)


def decode_hello_ack(data: bytes) -> tuple[list[int], dict[int, tuple[str, bytes]]]:
    """``(done, {segment: (sender, envelope)})`` of :func:`encode_hello_ack`.

    Parameters
    ----------
    data : bytes

    Raises
    ------
    MessageError
    """
    data = bytes(data)
    if len(data) < 4:
        raise MessageError("hello ack: truncated")
    (n,) = struct.unpack_from("<I", data)
    head = decode_json(data[4:4 + n], "hello ack")
    body = data[4 + n:]
    try:
        done = [int(s) for s in head["done"]]
        waiting = {int(s): (str(v), body[int(o):int(o) + int(k)]) for s, v, o, k in head["waiting"]}
    except (KeyError, TypeError, ValueError) as err:
        raise MessageError(f"hello ack: malformed header ({err})") from None
    return done, waiting


class Service:
    """The roadside service on one store.

    Parameters
    ----------
    store : ServiceStore
    trust : FleetTrust
        The fleet's trust anchor (authority key, revocations).
    log : callable, optional
        Called with one line per event (default: nothing).
    on_fused : callable, optional
        Called with ``(segment, store)`` after a contribution changed that segment's fused sums (e.g.
        :class:`roadcollab.network.roadsync.RoadSync`, which writes the road store).
    rounds : SecureRounds, optional
        Secure aggregation (:mod:`roadcollab.network.rounds`): contributions then add nothing to the
        fused sums themselves; each segment's sums come from its rounds. Default: in the clear.
    """

    def __init__(self, store: ServiceStore, trust: FleetTrust, *, log: Callable[[str], None] | None = None,
                 on_fused: Callable[[int, ServiceStore], None] | None = None,
                 rounds: "SecureRounds | None" = None) -> None:
        self.store, self.trust, self.plan = store, trust, store.plan
        self.topics = Topics(self.plan.fleet_id)
        self._log = log or (lambda line: None)
        self.on_fused = on_fused
        self.rounds = rounds
        if rounds is not None and rounds.on_fused is None:
            rounds.on_fused = on_fused

    @property
    def subscriptions(self) -> list[str]:
        """Topic filters the service reads."""
        return [self.topics.from_vehicles] + ([self.rounds.subscription] if self.rounds is not None else [])

    def on_connect(self) -> list[Publish]:
        """The retained waiting messages again (a restarted broker may have lost them), and the current
        phase of every round a restarted service continues."""
        out = [Publish(self.topics.waiting(s), encode_waiting(v, env), retain=True)
               for s, v, env in self.store.latest()]
        if self.rounds is not None:
            out += self.rounds.resend
            self.rounds.resend = []
        return out

    def tick(self) -> list[Publish]:
        """Timeouts (secure aggregation's phases and waiting rosters); call it about once a second."""
        return [] if self.rounds is None else self.rounds.tick()

    def _refuse(self, reason: str, vid: str | None, topic: str) -> list[Publish]:
        self.store.log("refused", reason, vid=vid, topic=topic)
        self._log(f"refused {topic}: {reason}")
        return []

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one received message; the replies to publish.

        Parameters
        ----------
        topic : str
        payload : bytes

        Returns
        -------
        list of Publish
            Empty for a refused message (the reason is in the store's events).
        """
        vid = None
        if self.rounds is not None and self.rounds.owns(topic):
            return self.rounds.handle(topic, payload)
        try:
            vid, kind, s = self.topics.parse_vehicle(topic)
            body = open_from(payload, self.trust, topic, vid)
            if kind == "hello":
                return self._hello(vid, decode_json(body, "hello"))
            if s is None:                      # parse_vehicle gives a segment for every "seg" topic
                raise MessageError(f"topic {topic!r}: expected .../v/<vid>/seg/<n>")
            return self._segment(vid, s, body, bytes(payload), topic)
        except (MessageError, ParameterError) as err:
            return self._refuse(str(err), vid, topic)

    def _hello(self, vid: str, hello: dict) -> list[Publish]:
        segs = hello.get("segments")
        if not isinstance(segs, list) or not all(isinstance(s, int) and 0 <= s < 10 ** 9 for s in segs) \
                or len(segs) > 100000:
            raise MessageError("hello: 'segments' must be a list of segment numbers")
        val, announced = hello.get("validated", []), set(segs)
        if not isinstance(val, list) or len(val) > len(announced) or not all(
                isinstance(s, int) and not isinstance(s, bool) and s in announced for s in val):
            raise MessageError("hello: 'validated' must be a list of the announced segment numbers")
        check_hello(self.plan, hello)                 # a fleet on a road: the hello is on it
        order = self.store.add_vehicle(vid, hello)
        waiting = {}
        for s in segs:
            p = self.store.predecessor(vid, s)
            if p is not None:
                waiting[s] = p
        self._log(f"hello from {vid} (vehicle {order + 1}): {len(segs)} segments, {len(waiting)} messages waiting")
        return [Publish(self.topics.ack(vid), encode_hello_ack(self.store.done_segments(vid), waiting))]

    def _segment(self, vid: str, s: int, body: bytes, envelope: bytes, topic: str) -> list[Publish]:
        hello = self.store.vehicle(vid)
        if hello is None:
            raise MessageError(f"a contribution from {vid} before its hello")
        if s not in hello.get("segments", []):
            raise MessageError(f"segment {s} is not among the segments {vid} announced")
        if self.rounds is not None:      # sealed to the fleet: the service checks only what it can read
            sealed_segment(body, s)
            outcome = self.store.add_sealed(vid, s, body, envelope)
        else:
            outcome = self.store.add_contribution(vid, decode_contribution(body, self.plan, s), body, envelope)
        ack = Publish(self.topics.ack(vid), encode_json({"type": "segment", "segment": s, "outcome": outcome}))
        if outcome == "conflict":
            self._refuse(f"segment {s}: {vid} already contributed other values (kept the first)", vid, topic)
            return [ack]
        if outcome == "duplicate":
            self.store.log("duplicate", f"segment {s} from {vid} again (applied once)", vid=vid, topic=topic)
            return [ack]
        self._log(f"segment {s}: accepted {vid}")
        out = [ack, Publish(self.topics.waiting(s), encode_waiting(vid, envelope), retain=True)]
        if self.rounds is not None:
            return out + self.rounds.maybe_open(s)
        if self.on_fused is not None:
            self.on_fused(s, self.store)
        return out
