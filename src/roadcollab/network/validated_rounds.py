"""The service's validated sessions: each segment's sum from a phased session with the helper aggregators.

Under ``[aggregation] mode = "validated"`` (:class:`~roadcollab.network.aggregation.AggregationPolicy`) the
service is the leader ``A`` of :mod:`~roadcollab.network.prioround` and other operators run the helpers
``B`` and ``C`` (``roadcollab helper``; one helper in a fleet enrolled with ``--aggregators 2``): every
vehicle proves its input inside the public box, then its deviations from the previous results inside an l2
ball (centred clipping), so no vehicle of a session moves its result by more than about ``R / (n - 1)``; no
aggregator alone learns an input, and with three aggregators one that deviates is caught.

The rounds keep :class:`~roadcollab.network.rounds.SecureRounds`' rules and store: one open session per
segment, claimed in the store; a vehicle gives one measurement of a segment to one session (its
:class:`~roadcollab.privacy.secagg_store.SessionLedger` refuses a second); epochs count the sessions. Two
rules differ:

- **Roster.** Only vehicles that covered every grid point of the segment are invited (the input is the
  inversion alone, :func:`~roadcollab.network.aggregation.validated_input`); a vehicle says which segments
  it covered so in its hello (``"validated"``, :func:`~roadcollab.network.aggregation.validated_segments`).
- **Restart.** The leader holds its shares of a running session in memory only, so a session this service
  held when it stopped is closed as aborted when it restarts (or another service adopts it); its vehicles
  have spent that measurement (privacy before liveness). Sessions therefore do not move between services:
  ``serve --shared`` is refused with validated aggregation.

Every helper's key advert (retained on ``{prefix}/prio/key/{helper_id}``, signed by its certified identity)
must have arrived before a session opens; the service's own advert is published (retained) on connect.
"""

from __future__ import annotations

import time
from typing import Callable


from ..errors import MessageError, ParameterError
from ..privacy.secagg_store import ReleaseLog
from ..wire.identity import FleetTrust
from .aggregation import AggregationPolicy, sums_from_mean, validated_params
from .prioround import PrioLeader, closed_notices
from .priowire import AggregatorKeys, PrioTopics, key_topic, open_advert
from .rounds import SecureRounds
from .service import Publish
from .store import ServiceStore

__all__ = ["ValidatedRounds"]


class ValidatedRounds(SecureRounds):
    """Validated sessions of every segment on one service store (module docstring).

    Parameters
    ----------
    store : ServiceStore
    trust : FleetTrust
    policy : AggregationPolicy
        ``mode`` must be ``validated``.
    prefix : str
        ``rc/{fleet_id}``.
    keys : AggregatorKeys
        The service's identity as the leader (certificate id ``aggregator-a``) and its X25519 key.
    release_log : ReleaseLog
        The leader's persistent record of released sum shares.
    helper_adverts : dict, optional
        Helper id to its signed key advert, where known; the others are read from their retained topics.
    log, on_fused, phase_timeout_s, round_wait_s, clock, owner, lease_s
        As :class:`~roadcollab.network.rounds.SecureRounds`.
    """

    def __init__(self, store: ServiceStore, trust: FleetTrust, policy: AggregationPolicy, prefix: str, *,
                 keys: AggregatorKeys, release_log: ReleaseLog, helper_adverts: dict[str, bytes] | None = None,
                 log: Callable[[str], None] | None = None, on_fused=None, phase_timeout_s: float = 20.0,
                 round_wait_s: float = 60.0, clock: Callable[[], float] = time.time, owner: str = "serve",
                 lease_s: float = 10.0) -> None:
        if not isinstance(policy, AggregationPolicy) or not policy.validated:
            raise ParameterError("ValidatedRounds needs an AggregationPolicy with mode 'validated'")
        self.params = validated_params(store.plan, policy)
        if keys.party != self.params.leader_id:
            raise ParameterError(f"the service leads as {self.params.leader_id!r}, got the keys of {keys.party!r}")
        self.keys, self.release_log = keys, release_log
        # Set before the base class adopts (and may reopen) this service's rounds.
        self.helper_adverts: dict[str, bytes] = {}
        for party, advert in (helper_adverts or {}).items():
            self.helper_adverts[party] = self._helper(party, advert, trust, prefix)
        super().__init__(store, trust, policy, prefix, log=log, on_fused=on_fused, phase_timeout_s=phase_timeout_s,
                         round_wait_s=round_wait_s, clock=clock, owner=owner, lease_s=lease_s)
        self.resend.insert(0, Publish(key_topic(prefix, keys.party), keys.advert(prefix), retain=True))

    def _helper(self, party: str, advert: bytes, trust: FleetTrust, prefix: str) -> bytes:
        """``advert`` if it is helper ``party``'s key advert (MessageError otherwise)."""
        if party not in self.params.helper_ids:
            raise MessageError(f"{party!r} is not a helper of this fleet")
        open_advert(advert, trust, prefix, party)
        return bytes(advert)

    def _adopt(self) -> list[Publish]:
        """Sessions this service held before a restart (or another's whose lease ran out) are closed as
        aborted: their shares are gone (module docstring)."""
        out: list[Publish] = []
        now = self.clock()
        for key in self.store.adopt_rounds(self.owner, now, now + self.lease_s):
            if key in self.active:
                continue
            row = next(r for r in self.store.rounds(key[0]) if r["epoch"] == key[1])
            reason = "the leader restarted during the session"
            # nobody waits for it: the helpers and the roster are told it closed
            out += closed_notices(PrioTopics(self.prefix, *key), self.keys, list(row["roster"]), "aborted", reason)
            out += self._closed(key, "aborted", list(row["roster"]), [], reason,
                                "aborted (the leader restarted during the session; its vehicles' measurement is spent)")
        return out

    @property
    def subscription(self) -> str:
        return f"{self.prefix}/prio/#"

    def owns(self, topic: str) -> bool:
        return topic.startswith(f"{self.prefix}/prio/")

    def free(self, segment: int) -> list[tuple[str, float]]:
        """As :meth:`SecureRounds.free`, of the vehicles whose hello lists ``segment`` as covered whole.

        Parameters
        ----------
        segment : int
        """
        out = []
        for v, t in super().free(segment):
            val = (self.store.vehicle(v) or {}).get("validated")
            if isinstance(val, list) and segment in val:
                out.append((v, t))
        return out

    def open_round(self, key: tuple[int, int], roster: list[str]) -> list[Publish]:
        """Open session ``key`` with ``roster`` once every helper's advert is known.

        Parameters
        ----------
        key : (int, int)
        roster : list of str
        """
        if len(self.helper_adverts) < len(self.params.helper_ids):
            return []
        adverts = [self.helper_adverts[h] for h in self.params.helper_ids]
        co = PrioLeader(self.prefix, *key, self.params, self.trust, self.keys, adverts, self.release_log)
        out = co.open(roster)
        if not self.store.open_round(*key, roster, owner=self.owner, lease_s=self.clock() + self.lease_s):
            return []
        self.active[key] = co      # type: ignore[assignment]  # a PrioLeader: the round interface SecureRounds drives
        self.phase_since[key] = self.clock()
        self._log(f"session {key[0]}/{key[1]}: opened with {len(roster)} vehicles {roster}, "
                  f"{self.params.phases} phases")
        return out

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one session message (a vehicle's upload, a helper's message or key advert).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        party = next((h for h in self.params.helper_ids if topic == key_topic(self.prefix, h)), None)
        if party is not None:
            try:
                self.helper_adverts[party] = self._helper(party, bytes(payload), self.trust, self.prefix)
            except MessageError as err:
                self.store.log("refused", f"{topic}: {err}", topic=topic)
                return []
            self._log(f"the key advert of helper {party} arrived")
            return [p for s in self._waiting_segments() for p in self.maybe_open(s)]
        if topic.startswith(f"{self.prefix}/prio/key/"):
            return []
        try:
            s, e, rest = PrioTopics.parse(self.prefix, topic)
        except MessageError as err:
            self.store.log("refused", str(err), topic=topic)
            return []
        if rest[:1] in (["to"], ["fwd"]) or rest == ["agg", self.params.leader_id]:
            return []                                 # the service's own messages
        co = self.active.get((s, e))
        if co is None:
            self.store.log("refused", f"{topic}: no session {s}/{e} is open here", topic=topic)
            return []
        return self._step((s, e), co, co.handle(topic, bytes(payload)))

    def _step(self, key, co, out: list[Publish]) -> list[Publish]:
        self._record_events(key, co, "prio")
        if out:
            self.phase_since[key] = self.clock()      # progress: the phase's timeout starts again
        if co.done:
            out = out + self._close(key, co)
        return out

    def _close(self, key, co) -> list[Publish]:
        self.phase_since.pop(key, None)
        vids = {i: v for v, i in co.pid.items()}
        used = [vids[i] for i in sorted(co.answered)]
        silent = [v for v in co.pid if co.pid[v] not in co.answered]
        reason = next((r for k, r in reversed(co.events) if k in ("finished", "aborted")), co.state)
        if co.state == "finished" and co.result is not None:
            total, count = sums_from_mean(self.store.plan, co.result, len(co.accepted))
            return self._closed(key, "finished", used, silent, reason, f"finished, {reason}", total, count)
        return self._closed(key, "aborted", used, silent, reason, f"aborted ({reason})")
