"""The service's secure-aggregation rounds: when each opens, who is invited, what its sum does.

Under ``[aggregation] mode = "secure"`` (:class:`~roadcollab.network.aggregation.AggregationPolicy`) the
service adds no inversion to a segment's fused sums itself; every sum comes from a round of
:class:`~roadcollab.network.secround.RoundCoordinator` over the vehicles that passed the segment.

Roster rule (a count rule, the same for every segment): the round of segment ``s`` opens as soon as
``round_size`` vehicles that contributed to ``s`` are free, i.e. not in an open round of ``s``, not
*used* by a closed one (their masked input went into it: a vehicle gives one measurement of a segment
to one round, so two rounds have nothing to difference) and not *silent* in an aborted one (invited,
never answered: gone). The first ``round_size`` free vehicles in arrival order are invited. When fewer
are free, a round of at least ``k = min_inputs`` opens once the longest-waiting free vehicle has waited
``round_wait_s``. One round per segment is open at a time; epochs count the rounds of a segment.

Each phase closes when every expected message has arrived, or after ``phase_timeout_s`` with what
arrived (:meth:`RoundCoordinator.advance`): a vehicle that died after dealing its shares is left
behind and its masks removed if ``t`` vehicles reveal (Bonawitz et al. 2017 dropout recovery).

Every accepted message and timeout is journalled in the store (the coordinator holds no secret), so a
service killed mid-round and restarted on its store replays the round and sends its current phase's
messages again; vehicles answer a repeated request with their first answer.

Several services on one store (``serve --shared``): a round is opened by a claim in the store
(:meth:`ServiceStore.open_round`, one transaction: one open round per segment, whoever opens it), and
its coordinator holds a lease it renews every tick (:meth:`ServiceStore.adopt_rounds`). Every service receives every round message (the
round topics are not shared-subscribed) and answers only those of the rounds it holds. When a service
stops renewing (killed, cut off), another takes its rounds over once the lease has run out
(:meth:`ServiceStore.adopt_rounds`) by the same journal replay as a restart. The store fences the old
holder: a journal entry or a round's close from a service that lost the round is refused
(:class:`~roadcollab.network.store.LostRound`), so a sum is added once.
"""

from __future__ import annotations

import time
from typing import Callable

from ..errors import MessageError, ParameterError
from ..wire.identity import FleetTrust
from .aggregation import AggregationPolicy, sums_from_total
from .secround import RoundCoordinator, RoundTopics
from .service import Publish
from .roundstore import CLOSED, LostRound
from .store import ServiceStore

__all__ = ["SecureRounds"]


class SecureRounds:
    """Rounds of every segment on one service store.

    Parameters
    ----------
    store : ServiceStore
    trust : FleetTrust
    policy : AggregationPolicy
        ``mode`` must be ``secure``.
    prefix : str
        Topic root of the fleet (``rc/{fleet_id}``).
    log : callable, optional
        One line per event.
    on_fused : callable, optional
        ``(segment, store)`` after a round's sum was added (as :class:`~roadcollab.network.service.Service`).
    phase_timeout_s, round_wait_s : float
        Module docstring.
    clock : callable
        Wall-clock seconds (tests).
    coordinator : type, optional
        The :class:`~roadcollab.network.secround.RoundCoordinator` class of every round (a subclass plays a
        deviating service in the attack tests).
    owner : str
        This service's name in the store's ``round_owners`` (unique per running service when several
        share a store; the same name after a restart adopts its rounds at once).
    lease_s : float
        How long a claim on a round holds without a renewal (seconds; renewed every :meth:`tick`).
    """

    def __init__(self, store: ServiceStore, trust: FleetTrust, policy: AggregationPolicy, prefix: str, *,
                 log: Callable[[str], None] | None = None, on_fused=None, phase_timeout_s: float = 20.0,
                 round_wait_s: float = 60.0, clock: Callable[[], float] = time.time,
                 coordinator: type[RoundCoordinator] = RoundCoordinator, owner: str = "serve",
                 lease_s: float = 10.0) -> None:
        if not isinstance(policy, AggregationPolicy) or not policy.secure:
            raise ParameterError("SecureRounds needs an AggregationPolicy with mode 'secure'")
        self.store, self.trust, self.policy, self.prefix = store, trust, policy, prefix
        self.spec = policy.spec
        self._log = log or (lambda line: None)
        self.on_fused = on_fused
        self.phase_timeout_s, self.round_wait_s, self.clock = float(phase_timeout_s), float(round_wait_s), clock
        self.coordinator = coordinator
        self.owner, self.lease_s = str(owner), float(lease_s)
        self.active: dict[tuple[int, int], RoundCoordinator] = {}
        self.phase_since: dict[tuple[int, int], float] = {}
        self.resend: list[Publish] = []
        self.resend += self._adopt()                # a restarted service continues its open rounds

    def _adopt(self) -> list[Publish]:
        """Replay the open rounds this service holds now but not in memory (its own after a restart, or
        another service's whose lease ran out); the messages of their current phases."""
        out: list[Publish] = []
        now = self.clock()
        for key in self.store.adopt_rounds(self.owner, now, now + self.lease_s):
            if key in self.active:
                continue
            co, last = self.coordinator.replay(self.prefix, *key, self.spec, self.trust, self.store.journal(*key))
            self.active[key] = co
            self.phase_since[key] = now
            self._log(f"round {key[0]}/{key[1]}: taken over in phase {co.phase}")
            out += last
            if co.done:                             # killed between its last message and its close
                out += self._close(key, co)
        return out

    @property
    def subscription(self) -> str:
        """The service's filter of every round message from the vehicles."""
        return f"{self.prefix}/secagg/+/+/+/+"

    def owns(self, topic: str) -> bool:
        """True for a round topic of this fleet.

        Parameters
        ----------
        topic : str
        """
        return topic.startswith(f"{self.prefix}/secagg/")

    # -- rosters -----------------------------------------------------------------------------------
    def free(self, segment: int) -> list[tuple[str, float]]:
        """``(vid, since_s)`` of the vehicles a new round of ``segment`` may invite, in arrival order.

        Parameters
        ----------
        segment : int
        """
        busy: set[str] = set()
        since: dict[str, float] = {}
        for r in self.store.rounds(segment):
            if r["phase"] not in CLOSED:
                busy |= set(r["roster"])
            else:
                busy |= set(r["used"]) | set(r["silent"])
                for v in r["roster"]:                # free again after an aborted round: waits anew
                    since[v] = max(since.get(v, 0.0), r["closed_s"] or 0.0)
        return [(v, max(t, since.get(v, t))) for v, t in self.store.contributors(segment) if v not in busy]

    def _epoch(self, segment: int) -> int:
        rs = self.store.rounds(segment)
        return 1 + max(r["epoch"] for r in rs) if rs else 0

    def maybe_open(self, segment: int) -> list[Publish]:
        """Open the next round of ``segment`` if the roster rule allows (module docstring).

        Parameters
        ----------
        segment : int
        """
        rounds = self.store.rounds(segment)
        if any(r["phase"] not in CLOSED for r in rounds):     # one open round per segment, of any service
            return []
        free = self.free(segment)
        n = self.policy.round_size
        waited = self.clock() - min((t for _, t in free), default=self.clock())
        if len(free) < n and not (len(free) >= self.spec.min_inputs and waited >= self.round_wait_s):
            return []
        roster = [v for v, _ in free[:n]]
        key = (segment, self._epoch(segment))
        return self.open_round(key, roster)

    def open_round(self, key: tuple[int, int], roster: list[str]) -> list[Publish]:
        """Open round ``key = (segment, epoch)`` with ``roster`` (what :meth:`maybe_open` decided).

        Parameters
        ----------
        key : (int, int)
        roster : list of str
        """
        co = self.coordinator(self.prefix, *key, self.spec, self.trust)
        out = co.open(roster)
        if not self.store.open_round(*key, roster, owner=self.owner, lease_s=self.clock() + self.lease_s):
            return []                               # another service opened the segment's round first
        co.journal.clear()                          # the store's open entry stands for it
        self.active[key] = co
        self.phase_since[key] = self.clock()
        self._log(f"round {key[0]}/{key[1]}: opened with {len(roster)} vehicles {roster}")
        return out

    # -- messages ------------------------------------------------------------------------------------
    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one round message from a vehicle; the replies (refusals go to the store's events).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        try:
            s, e, rest = RoundTopics.parse_round(self.prefix, topic)
        except MessageError as err:
            self.store.log("refused", str(err), topic=topic)
            return []
        if rest[:1] == ["to"]:
            return []                                 # the service's own messages
        key = (s, e)
        co = self.active.get(key)
        if co is None:
            known = [r for r in self.store.rounds(s) if r["epoch"] == e]
            if known and known[0]["phase"] not in CLOSED:
                return []                             # another service's round (it got this message too)
            why = f"round {s}/{e} is {known[0]['phase']}" if known else f"no round {s}/{e} was opened"
            self.store.log("refused", f"{topic}: {why}", vid=rest[-1] if rest else None, topic=topic)
            return []
        return self._step(key, co, co.handle(topic, bytes(payload)))

    def _record_events(self, key: tuple[int, int], co, what: str = "secagg") -> None:
        """A round's refusals and duplicates into the store's events, and out of the round's own list."""
        for kind, reason in co.events:
            if kind in ("refused", "duplicate"):
                self.store.log(kind, reason, topic=f"{self.prefix}/{what}/{key[0]}/{key[1]}")
        co.events[:] = [ev for ev in co.events if ev[0] not in ("refused", "duplicate")]

    def _step(self, key: tuple[int, int], co: RoundCoordinator, out: list[Publish]) -> list[Publish]:
        self._record_events(key, co)
        if co.journal:
            try:
                self.store.journal_add(*key, co.journal, co.phase, owner=self.owner)
            except LostRound as err:
                return self._lost(key, err)
            co.journal.clear()
            self.phase_since[key] = self.clock()
        if co.done:
            out = out + self._close(key, co)
        return out

    def _lost(self, key: tuple[int, int], err: LostRound) -> list[Publish]:
        """Drop a round another service took over: nothing this service holds of it is sent or written."""
        self.active.pop(key, None)
        self.phase_since.pop(key, None)
        self._log(f"round {key[0]}/{key[1]}: lost ({err})")
        return []

    def _close(self, key: tuple[int, int], co: RoundCoordinator) -> list[Publish]:
        self.phase_since.pop(key, None)
        answered = {i for i in co.got["adverts"]}
        silent = [v for v in co.roster if co.pid[v] not in answered]
        reason = next((r for k, r in reversed(co.events) if k in ("finished", "aborted")), co.phase)
        if co.phase == "finished" and co.result is not None:
            try:
                total, count = sums_from_total(self.store.plan, co.result.result.total)
            except ParameterError as err:
                return self._closed(key, "aborted", co.used, silent, str(err), f"sum refused ({err})")
            return self._closed(key, "finished", co.used, silent, reason, f"finished, {reason}", total, count)
        return self._closed(key, "aborted", co.used, silent, reason, f"aborted ({reason})")

    def _closed(self, key, phase, used, silent, reason, line, total=None, count=None) -> list[Publish]:
        try:
            self.store.close_round(key[0], key[1], phase, used=used, silent=silent, reason=reason, total=total, count=count,
                                   owner=self.owner)
        except LostRound as err:
            return self._lost(key, err)
        self.active.pop(key, None)
        self._log(f"round {key[0]}/{key[1]}: {line}")
        if total is not None and self.on_fused is not None:
            self.on_fused(key[0], self.store)
        return self.maybe_open(key[0])

    def tick(self) -> list[Publish]:
        """Phase timeouts and waiting rosters; call it about once a second.

        Returns
        -------
        list of Publish
        """
        now = self.clock()
        out: list[Publish] = self._adopt()          # renews this service's leases, takes over expired ones
        for key, co in list(self.active.items()):
            if now - self.phase_since.get(key, now) >= self.phase_timeout_s:
                self._log(f"round {key[0]}/{key[1]}: phase {co.phase} timed out")
                out += self._step(key, co, co.advance())
        if self.round_wait_s >= 0:
            for s in self._waiting_segments():
                out += self.maybe_open(s)
        return out

    def _waiting_segments(self) -> list[int]:
        seen = {r["segment"] for r in self.store.rounds() if r["phase"] not in CLOSED}
        return [s for s in self.store.contributed_segments() if s not in seen]
