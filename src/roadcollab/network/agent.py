"""A vehicle's protocol: a state machine from the service's replies to the messages it publishes.

``hello`` (its segments) -> the service replies with the messages waiting for it and the segments it
already applied (a restarted vehicle skips those) -> the vehicle checks every waiting message (the
guard: a valid signature of a fleet vehicle on that segment's topic, a well-formed contribution on
that segment; anything else is dropped and Algorithm 1 runs without it there) -> runs the engine ->
publishes one contribution per segment -> done when every segment is acknowledged. Unacknowledged
messages are sent again by :meth:`VehicleAgent.resend` (the service applies each once).

Under secure aggregation (a :class:`~roadcollab.network.secround_agent.RoundAgent` given as ``rounds``)
the vehicle also takes part in each of its segments' rounds with its inversion on that segment (the
rounds' ``round_input``: :func:`~roadcollab.network.aggregation.segment_input`, or under validated
aggregation, a :class:`~roadcollab.network.prioagent.PrioAgent` as ``rounds``, the segments it covered whole
only); it is :attr:`~VehicleAgent.done` when every
segment is acknowledged and a round has closed with its input in it (:attr:`~VehicleAgent.contributed`
says only the first).
"""

from __future__ import annotations

from ..errors import MessageError, ParameterError
from ..wire.identity import FleetTrust, VehicleIdentity
from .engine import VehicleEngine
from .messages import Topics, decode_contribution, decode_json, encode_contribution, encode_json, \
    encode_sealed_relay, open_from, open_sealed_relay, seal
from .service import Publish, decode_hello_ack

__all__ = ["VehicleAgent"]


class VehicleAgent:
    """One vehicle on the network.

    Parameters
    ----------
    engine : VehicleEngine
        Its drive, inverted.
    identity : VehicleIdentity
        Its key and certificate.
    trust : FleetTrust
        The fleet's trust anchor (to check the waiting messages).
    hello_extra : dict, optional
        More hello fields (a fleet on a road: :func:`roadcollab.network.fleetroad.hello_fields`); they
        never replace the fields the agent writes.
    realign : callable, optional
        ``realign(engine, checked) -> engine``: the engine again with its positions corrected against the
        checked waiting contributions, before it computes its own (a fleet on a road:
        :func:`roadcollab.network.fleetroad.align_to_waiting`, whose engine contributes only on the
        segments the hello announced).
    rounds : RoundAgent, optional
        Its side of the secure-aggregation rounds (module docstring); default: in the clear.
    relay_key : RelayKey, optional
        The fleet's relay key; required with ``rounds`` (the waiting messages are sealed to it).
    """

    def __init__(self, engine: VehicleEngine, identity: VehicleIdentity, trust: FleetTrust, *,
                 hello_extra: dict | None = None, realign=None, rounds=None, relay_key=None) -> None:
        if rounds is not None and relay_key is None:
            raise ParameterError("secure aggregation needs the fleet's relay key (relay.key in the vehicle folder)")
        self.engine, self.identity, self.trust, self.rounds = engine, identity, trust, rounds
        self.relay_key = relay_key
        # the rounds' own hello fields (a validated fleet: the segments covered whole), computed once
        self.hello_extra = {**(hello_extra or {}), **(rounds.hello_fields(engine) if rounds is not None else {})}
        self.realign = realign
        self.vid = identity.vehicle_id
        self.topics = Topics(engine.plan.fleet_id)
        self.segments = engine.segments
        self.pending: dict[int, Publish] = {}
        self.outcomes: dict[int, str] = {}
        self.dropped: list[str] = []
        self.started = False

    @property
    def subscriptions(self) -> list[str]:
        """Topics to subscribe to before :meth:`start`."""
        return [self.topics.ack(self.vid)] + ([self.rounds.subscription] if self.rounds is not None else [])

    @property
    def contributed(self) -> bool:
        """Every segment has an outcome from the service."""
        return self.started and not self.pending and set(self.outcomes) >= set(self.segments)

    @property
    def rounds_left(self) -> list[int]:
        """Segments whose round has not yet closed with this vehicle's input (secure aggregation)."""
        if self.rounds is None:
            return []
        return [s for s in sorted(self.rounds.inputs) if not self.rounds.finished(s)]

    @property
    def done(self) -> bool:
        """Every segment acknowledged, and (secure aggregation) every round closed with its input."""
        return self.contributed and not self.rounds_left

    def hello(self) -> Publish:
        d = self.engine.drive
        body = encode_json({**self.hello_extra, "segments": self.segments, "speed_mps": float(d.speed), "csv": d.csv_path.name,
                            "n_samples": int(d.n_samples), "start_m": float(d.positions[0]),
                            "end_m": float(d.positions[-1])})
        topic = self.topics.hello(self.vid)
        return Publish(topic, seal(self.identity, topic, body))

    def start(self) -> list[Publish]:
        """The first message (the hello)."""
        return [self.hello()]

    def resend(self) -> list[Publish]:
        """What is not acknowledged yet: the hello before the reply, else the pending contributions."""
        return [self.hello()] if not self.started else list(self.pending.values())

    def _check_waiting(self, s: int, sender: str, envelope: bytes):
        topic = self.topics.segment(sender, s)
        body = open_from(envelope, self.trust, topic, sender)
        if self.rounds is not None:
            return open_sealed_relay(body, self.relay_key, topic, self.engine.plan, s)
        return decode_contribution(body, self.engine.plan, s)

    def on_message(self, topic: str, payload: bytes) -> list[Publish]:
        """React to a message from the service; what to publish. Malformed replies are dropped.

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        if self.rounds is not None and topic != self.topics.ack(self.vid):
            return self.rounds.on_message(topic, payload)
        if topic != self.topics.ack(self.vid):
            return []
        try:
            if bytes(payload[:1]) == b"{":
                return self._segment_ack(decode_json(payload, "ack"))
            if self.started:
                return []                                 # a second reply to a resent hello
            done, waiting = decode_hello_ack(payload)
        except (MessageError, ParameterError) as err:
            self.dropped.append(str(err))
            return []
        checked = {}
        for s, (sender, env) in waiting.items():
            if s not in self.segments:
                continue
            try:
                checked[s] = self._check_waiting(s, sender, env)
            except (MessageError, ParameterError) as err:   # the guard: never learn from what does not verify
                self.dropped.append(f"segment {s}: {err}")
        self.started = True
        for s in done:
            self.outcomes[s] = "accepted"
        if self.realign is not None and checked:
            self.engine = self.realign(self.engine, checked)
        out = []
        for c in self.engine.contributions(checked):
            if self.rounds is not None and c.segment not in self.rounds.inputs:
                u = self.rounds.round_input(self.engine.plan, c)   # None: no part in that round
                if u is not None:
                    self.rounds.inputs[c.segment] = u
            if c.segment in self.outcomes:
                continue
            t = self.topics.segment(self.vid, c.segment)
            body = encode_contribution(c) if self.rounds is None else encode_sealed_relay(c, self.relay_key, t)
            self.pending[c.segment] = Publish(t, seal(self.identity, t, body))
            out.append(self.pending[c.segment])
        for s in self.segments:                              # covered by fewer than one finite point
            if s not in self.pending and s not in self.outcomes:
                self.outcomes[s] = "empty"
        return out

    def _segment_ack(self, ack: dict) -> list[Publish]:
        s = ack.get("segment")
        if isinstance(s, int) and s in self.pending and ack.get("outcome") in ("accepted", "duplicate", "conflict"):
            self.outcomes[s] = ack["outcome"]
            del self.pending[s]
        return []
