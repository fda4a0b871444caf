"""One segment's secure-aggregation round as messages between the service and the vehicles.

The active protocol of :mod:`roadcollab.privacy.secagg_active` (Bonawitz et al. 2017, signed adverts
bound to fleet identities, committed shares, consistency round on ``U_3``, one input per segment and
epoch kept in each vehicle's :class:`~roadcollab.privacy.secagg_store.SessionLedger`) driven as
``(topic, payload)`` messages, with no transport of its own: :class:`RoundCoordinator` is the service's
side, :class:`~roadcollab.network.secround_agent.RoundAgent` a vehicle's;
:func:`~roadcollab.network.secround_agent.pump` moves their messages over any
:class:`~roadcollab.network.transport.Transport` (a :class:`~roadcollab.network.transport.MemoryBroker`
in the fast tests).

Topics of round ``(segment, epoch)`` under ``{prefix}/secagg/{segment}/{epoch}`` (the service uses the
fleet's topic root ``rc/{fleet_id}`` as ``prefix``, so the broker's ACL covers them):

- ``.../{kind}/{vid}``, vehicle -> service, ``kind`` in ``advert``, ``shares``, ``masked``, ``sign``,
  ``reveal``; every payload sealed by the vehicle's identity for that topic
  (:func:`~roadcollab.network.messages.seal`), so the service knows its sender;
- ``.../to/{vid}``, service -> vehicle: ``invite`` (its protocol id), ``roster`` (``U_1``, signed
  adverts), ``dealt`` (the sealed shares other vehicles dealt it and every signed commitment),
  ``survivors`` (``U_3``), ``signatures`` (the consistency signatures), and ``closed`` to every member
  of the roster when the round ends (``outcome`` ``finished`` or ``aborted``, ``reason``, ``used``: the
  protocol ids whose masked input the round consumed).

The sealed shares pass the service (Algorithm of Bonawitz et al.: the server routes them) but are
encrypted to their recipient with X25519 + AEAD, so the service reads none of them. Roster rule: the
``n`` certified vehicles the service names in :meth:`RoundCoordinator.open` (those that passed the
segment, by a count rule: the first ``n``), ``k <= n <= 2t - c - 1``.

Phases advance when every expected message of the phase has arrived, or when the service calls
:meth:`RoundCoordinator.advance` on its timeout (a vehicle that vanished after dealing its shares is
left behind; its masks are removed by reconstruction if at least ``t`` vehicles reveal). A vehicle that
advertised but dealt no shares aborts the round (every vehicle's masks of round 2 span all of ``U_1``):
the service opens a new round without it. A message for a finished or aborted round,
a duplicate, a message of a phase already closed, or one that does not verify is refused, with its
reason in :attr:`RoundCoordinator.events`; nothing a vehicle sends raises out of ``handle``.

The coordinator holds no secret: its state is a function of the roster, the messages it accepted and
the timeouts it took, in order (:attr:`RoundCoordinator.journal`). :meth:`RoundCoordinator.replay`
rebuilds it from that journal, so a service killed mid-round and restarted on its store continues the
round (:mod:`roadcollab.network.rounds`).
"""

from __future__ import annotations

import json

import numpy as np

from ..errors import MessageError, ParameterError
from ..privacy.secagg_active import VerifiedAggregate, unmask_verified, verify_roster
from ..privacy.secagg_messages import SecAggSpec, session_id
from ..wire.identity import FleetTrust
from ..wire.protocol import decode
from ..wire.secagg import MaskedInput, Reveal
from .messages import b64 as _b64, open_from, unb64 as _unb64
from .service import Publish

__all__ = ["RoundTopics", "RoundCoordinator", "PHASES"]

PHASES = ("adverts", "shares", "masked", "consistency", "reveal", "finished", "aborted")
_KIND_OF_PHASE = {"adverts": "advert", "shares": "shares", "masked": "masked", "consistency": "sign",
                  "reveal": "reveal"}


def _json(data: bytes, what: str) -> dict:
    try:
        obj = json.loads(bytes(data).decode())
    except (UnicodeDecodeError, ValueError):
        raise MessageError(f"{what}: not JSON") from None
    if not isinstance(obj, dict):
        raise MessageError(f"{what}: expected a JSON object")
    return obj


def _int_map(obj, what: str) -> dict:
    if not isinstance(obj, dict) or len(obj) > 10000:
        raise MessageError(f"{what}: expected an object of protocol ids")
    try:
        return {int(k): _unb64(v, what) for k, v in obj.items()}
    except (TypeError, ValueError):
        raise MessageError(f"{what}: keys must be protocol ids") from None


class RoundTopics:
    """Topic names of one round.

    Parameters
    ----------
    fleet_id : str
    segment, epoch : int
    """

    def __init__(self, fleet_id: str, segment: int, epoch: int) -> None:
        self.base = f"{fleet_id}/secagg/{int(segment)}/{int(epoch)}"

    @staticmethod
    def parse_round(prefix: str, topic: str) -> tuple[int, int, list[str]]:
        """``(segment, epoch, rest)`` of any topic under ``{prefix}/secagg/``.

        Parameters
        ----------
        prefix : str
        topic : str

        Raises
        ------
        MessageError
        """
        head = f"{prefix}/secagg/"
        parts = topic[len(head):].split("/") if topic.startswith(head) else []
        if len(parts) < 3 or not all(p.isascii() and p.isdigit() and len(p) <= 9 for p in parts[:2]):
            raise MessageError(f"topic {topic!r} is not a round topic under {head}")
        return int(parts[0]), int(parts[1]), parts[2:]

    def up(self, kind: str, vid: str) -> str:
        """Vehicle -> service.

        Parameters
        ----------
        kind : str
            ``advert``, ``shares``, ``masked``, ``sign`` or ``reveal``.
        vid : str
            The sending vehicle.
        """
        return f"{self.base}/{kind}/{vid}"

    def down(self, vid: str) -> str:
        """Service -> vehicle.

        Parameters
        ----------
        vid : str
            The receiving vehicle.
        """
        return f"{self.base}/to/{vid}"

    @property
    def from_vehicles(self) -> str:
        """The service's subscription."""
        return f"{self.base}/+/+"

    def parse_up(self, topic: str) -> tuple[str, str]:
        """``(kind, vid)`` of a vehicle -> service topic.

        Parameters
        ----------
        topic : str

        Raises
        ------
        MessageError
        """
        head, _, rest = topic.partition(self.base + "/")
        parts = rest.split("/")
        if head or len(parts) != 2 or parts[0] not in _KIND_OF_PHASE.values():
            raise MessageError(f"topic {topic!r} is not a round message of {self.base}")
        return parts[0], parts[1]


class RoundCoordinator:
    """The service's side of one round on one segment: routes, collects, unmasks.

    Parameters
    ----------
    fleet_id : str
        The topic prefix (``rc/{fleet_id}`` on the network).
    segment, epoch : int
        The measurement aggregated: ``session_id(segment, epoch)``.
    spec : SecAggSpec
    trust : FleetTrust

    Attributes
    ----------
    phase : str
        One of :data:`PHASES`.
    events : list of (str, str)
        ``(kind, reason)``: ``refused``, ``duplicate``, ``aborted``, ``finished``.
    average : (L, 2) ndarray or None
        The revealed sum over ``U_2`` divided by ``|U_2|``, m/s (once finished).
    journal : list of tuple
        ``("open", roster)``, ``("msg", topic, payload)`` for every accepted message, ``("advance",)``
        for every timeout, in order: what :meth:`replay` needs.
    """

    def __init__(self, fleet_id: str, segment: int, epoch: int, spec: SecAggSpec, trust: FleetTrust) -> None:
        if not isinstance(spec, SecAggSpec) or not isinstance(trust, FleetTrust):
            raise ParameterError("spec must be a SecAggSpec and trust a FleetTrust")
        self.segment, self.epoch, self.spec, self.trust = int(segment), int(epoch), spec, trust
        self.session = session_id(self.segment, self.epoch)
        self.topics = RoundTopics(fleet_id, self.segment, self.epoch)
        self.phase = "adverts"
        self.pid: dict[str, int] = {}
        self.got: dict[str, dict[int, bytes]] = {p: {} for p in _KIND_OF_PHASE}
        self.events: list[tuple[str, str]] = []
        self.average: np.ndarray | None = None
        self.result: VerifiedAggregate | None = None
        self.bytes_in = 0
        self.bytes_out = 0
        self.journal: list[tuple] = []

    @classmethod
    def replay(cls, fleet_id: str, segment: int, epoch: int, spec: SecAggSpec, trust: FleetTrust,
               journal) -> tuple["RoundCoordinator", list[Publish]]:
        """The coordinator rebuilt from its :attr:`journal`, and the messages of its current phase.

        Parameters
        ----------
        fleet_id : str
        segment, epoch : int
        spec : SecAggSpec
        trust : FleetTrust
        journal : iterable of tuple

        Returns
        -------
        RoundCoordinator
        list of Publish
            What the last step published (sent again after a restart: vehicles ignore copies).
        """
        co = cls(fleet_id, segment, epoch, spec, trust)
        last: list[Publish] = []
        for entry in journal:
            if entry[0] == "open":
                out = co.open(list(entry[1]))
            elif entry[0] == "msg":
                out = co.handle(entry[1], bytes(entry[2]))
            else:
                out = co.advance()
            if out:
                last = out
        co.events.clear()
        co.journal.clear()             # already in the store
        return co, last

    @property
    def roster(self) -> list[str]:
        """Vehicle ids invited, in protocol-id order."""
        return sorted(self.pid, key=self.pid.__getitem__)

    @property
    def used(self) -> list[str]:
        """Vehicles whose masked input this round received (their measurement of the segment is spent)."""
        ids = set(self.got["masked"])
        return [v for v in self.roster if self.pid[v] in ids]

    @property
    def done(self) -> bool:
        return self.phase in ("finished", "aborted")
    # -- hooks an attacking service overrides (honest: forward unchanged) --
    def relay_roster(self, vid: str, signed: dict) -> dict:
        return signed

    def relay_survivors(self, vid: str, survivors: list) -> list:
        return survivors

    def relay_signatures(self, vid: str, signatures: dict) -> dict:
        return signatures

    def _send(self, vid: str, obj: dict) -> Publish:
        payload = json.dumps(obj, separators=(",", ":")).encode()
        self.bytes_out += len(payload)
        return Publish(self.topics.down(vid), payload)

    def open(self, roster: list[str]) -> list[Publish]:
        """Invite the certified vehicles ``roster`` (vehicle ids); protocol ids ``1..n`` in that order.

        Parameters
        ----------
        roster : list of str
        """
        if len(set(roster)) != len(roster) or not roster:
            raise ParameterError("roster must be a non-empty list of distinct vehicle ids")
        self.pid = {v: i + 1 for i, v in enumerate(roster)}
        self.journal.append(("open", list(roster)))
        return [self._send(v, {"type": "invite", "id": i, "segment": self.segment, "epoch": self.epoch})
                for v, i in self.pid.items()]

    def _members(self, phase: str) -> list[str]:
        """Vehicles expected in ``phase``: those that answered the previous phase."""
        if phase == "adverts":
            return list(self.pid)
        prev = PHASES[PHASES.index(phase) - 1]
        ids = set(self.got[prev])
        return [v for v, i in self.pid.items() if i in ids]

    def _refuse(self, reason: str) -> list[Publish]:
        self.events.append(("refused", reason))
        return []

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one vehicle message; what to publish (empty when refused: reason in :attr:`events`).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        if topic.startswith(self.topics.base + "/to/"):
            return []                                   # its own messages to the vehicles
        try:
            kind, vid = self.topics.parse_up(topic)
            if self.phase in ("finished", "aborted"):
                return self._refuse(f"{topic}: round ({self.segment}, {self.epoch}) is {self.phase}")
            if vid not in self.pid:
                return self._refuse(f"{topic}: {vid} is not in the roster of this round")
            body = open_from(payload, self.trust, topic, vid)
            self.bytes_in += len(payload)
            phase = next(p for p, k in _KIND_OF_PHASE.items() if k == kind)
            i = self.pid[vid]
            if phase != self.phase:
                return self._refuse(f"{topic}: {kind} of {vid} arrived in phase {self.phase}")
            if vid not in self._members(phase):
                return self._refuse(f"{topic}: {vid} did not take part in the previous phase")
            if i in self.got[phase]:
                self.events.append(("duplicate" if self.got[phase][i] == body else "refused",
                                    f"{topic}: {kind} of {vid} again (applied once)"))
                return []
            self._check(phase, i, body)
            self.got[phase][i] = body
            self.journal.append(("msg", topic, bytes(payload)))
        except MessageError as err:
            return self._refuse(f"{topic}: {err}")
        if len(self.got[self.phase]) == len(self._members(self.phase)):
            return self._advance()
        return []

    def _check(self, phase: str, i: int, body: bytes) -> None:
        """Well-formedness of a vehicle's message (its content is checked again where it is used)."""
        if phase == "shares":
            obj = _json(body, "shares")
            _int_map(obj.get("sealed"), "shares.sealed")
            _unb64(obj.get("commitments"), "shares.commitments")
        elif phase in ("masked", "reveal"):
            m = decode(body)
            want = MaskedInput if phase == "masked" else Reveal
            if not isinstance(m, want) or m.vehicle != i or m.session != self.session:
                raise MessageError(f"{phase}: expected a {want.__name__} of vehicle {i} in this session")

    def advance(self) -> list[Publish]:
        """Close the current phase with what arrived (the service's timeout) and start the next.

        Returns
        -------
        list of Publish
        """
        if self.phase in ("finished", "aborted"):
            return []
        self.journal.append(("advance",))
        return self._advance()

    def _advance(self) -> list[Publish]:
        have = self.got.get(self.phase, {})
        if self.phase in ("finished", "aborted"):
            return []
        need = self.spec.threshold if self.phase == "reveal" else self.spec.min_inputs
        if len(have) < need:
            return self._abort(f"phase {self.phase}: {len(have)} vehicles answered, {need} required")
        vids = {i: v for v, i in self.pid.items()}
        if self.phase == "adverts":
            self.phase = "shares"
            signed = {str(i): _b64(b) for i, b in have.items()}
            return [self._send(vids[i], {"type": "roster", "adverts": self.relay_roster(vids[i], dict(signed))})
                    for i in sorted(have)]
        if self.phase == "shares":
            missing = sorted(set(self.got["adverts"]) - set(have))
            if missing:      # every mask of round 2 uses all of U_1: without their shares nothing unmasks
                return self._abort(f"phase shares: vehicles {missing} advertised keys but dealt no shares "
                                   f"(open a new round without them)")
            self.phase = "masked"
            dealt = {i: _json(b, "shares") for i, b in have.items()}
            coms = {str(d): o["commitments"] for d, o in dealt.items()}
            out = []
            for j in sorted(have):
                mine = {str(d): o["sealed"][str(j)] for d, o in dealt.items() if str(j) in o["sealed"]}
                out.append(self._send(vids[j], {"type": "dealt", "sealed": mine, "commitments": coms}))
            return out
        if self.phase == "masked":
            self.phase = "consistency"
            u3 = sorted(have)
            return [self._send(vids[i], {"type": "survivors", "ids": self.relay_survivors(vids[i], list(u3))})
                    for i in u3]
        if self.phase == "consistency":
            self.phase = "reveal"
            sigs = {str(i): _b64(b) for i, b in have.items()}
            return [self._send(vids[i], {"type": "signatures", "signatures": self.relay_signatures(vids[i], dict(sigs))})
                    for i in sorted(have)]
        return self._unmask()

    def _closed(self, outcome: str, reason: str) -> list[Publish]:
        used = sorted(self.got["masked"])
        return [self._send(v, {"type": "closed", "outcome": outcome, "reason": reason, "used": used})
                for v in self.roster]

    def _abort(self, reason: str) -> list[Publish]:
        self.phase = "aborted"
        self.events.append(("aborted", reason))
        return self._closed("aborted", reason)

    def _unmask(self) -> list[Publish]:
        try:
            signed = self.got["adverts"]
            roster = verify_roster(dict(signed), self.trust, self.session, self.spec)
            coms = {i: _unb64(_json(b, "shares")["commitments"], "commitments") for i, b in self.got["shares"].items()}
            # _check admitted only messages of the phase's type; decoded again, they are narrowed here
            masked = [m for m in map(decode, self.got["masked"].values()) if isinstance(m, MaskedInput)]
            reveals = [r for r in map(decode, self.got["reveal"].values()) if isinstance(r, Reveal)]
            agg = unmask_verified(roster, coms, masked, reveals, self.spec, self.trust)
        except MessageError as err:
            return self._abort(f"unmasking: {err}")
        self.result = agg
        self.average = agg.result.average
        self.phase = "finished"
        reason = f"{len(agg.result.survivors)} inputs, dropped {list(agg.result.dropped)}"
        self.events.append(("finished", reason))
        return self._closed("finished", reason)
