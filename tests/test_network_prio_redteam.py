"""A red team's attacks on the three-aggregator validated sessions, kept as regression tests (issue 20).

The root of the privacy breaks found: an FLP proof whose joint verifier is known at two query points gives
its input away (the random wire seed cancels, leaving two equations per gadget slot in a few dozen bits,
solved by meet-in-the-middle: every honest input recovered to the fixed-point step). Three routes gave a
deviating aggregator two points, each closed and asserted here by the property that blocks it: no honest
aggregator sends a verifier share unless all three agree on one view of the phase (roster, uploads' commitments,
every coin's commitment and opening), a party that sends two different messages of one kind is caught, and an
aggregator reveals one coin per (session, phase), ever (persisted). The fourth finding: messages that raised
out of ``handle`` (a deeply nested JSON header, a 5,000-digit id), one of which let a vehicle stall a session
unnamed.

The adversary's broker (:class:`Router`) delivers every message in order, through a hook that may change,
hold or drop a copy per recipient: a deviating leader running the broker.
"""

from __future__ import annotations

import struct

import numpy as np
from test_network_prio import PREFIX, _leader, _world

import roadcollab.network.prioagent as agent_mod
from roadcollab.network.messages import open_signed, seal
from roadcollab.network.priohelper import PrioHelperService
from roadcollab.network.priowire import pack, unpack
from roadcollab.privacy.secagg_messages import session_id
from roadcollab.privacy.secagg_phased import phase_session
from roadcollab.privacy.secagg_replicated import coin_commitment

B, C = "aggregator-b", "aggregator-c"
DEEP = b"[" * 30000 + b"]" * 30000


class Router:
    """The broker, run by the adversary: ``hook(topic, payload, recipient) -> payloads`` per copy."""

    def __init__(self, w, lead, hook=None):
        self.w, self.lead, self.hook = w, lead, hook or (lambda t, p, r: [p])
        self.queue: list = []
        self.delivered: list = []

    def recipients(self, topic):
        rest = topic[len(self.lead.topics.base) + 1:].split("/")
        if rest[0] == "to":
            return [("agent", rest[1])]
        if rest[0] == "up":
            return [("leader", None)]
        if rest[0] == "fwd":
            return [("helper", rest[1])]
        if rest[0] == "agg":
            out = [("helper", h) for h in self.w["params"].helper_ids if h != rest[1]]
            return out + ([("leader", None)] if rest[1] != self.w["params"].leader_id else [])
        return []

    def publish(self, topic, payload):
        for r in self.recipients(topic):
            self.queue.extend((r, topic, p) for p in self.hook(topic, payload, r))

    def run(self):
        helpers = {h.keys.party: h for h in self.w["helpers"]}
        while self.queue:
            (kind, who), topic, payload = self.queue.pop(0)
            self.delivered.append((kind, who, topic, payload))
            if kind == "agent":
                out = self.w["agents"][who].on_message(topic, payload)
            elif kind == "leader":
                out = self.lead.handle(topic, payload)
            else:
                out = helpers[who].handle(topic, payload)
            for p in out:
                self.publish(p.topic, p.payload)

    def session(self):
        for p in self.lead.open(list(self.w["agents"])):
            self.publish(p.topic, p.payload)
        self.run()
        for _ in range(3):
            if self.lead.done:
                break
            for p in self.lead.advance():
                self.publish(p.topic, p.payload)
            self.run()

    def sent(self, party, kind, phase):
        """The ``kind`` messages of ``phase`` that aggregator ``party`` published."""
        out = []
        for _, _, topic, payload in self.delivered:
            if topic.endswith(f"/agg/{party}"):
                h, _ = unpack(open_signed(payload, self.w["trust"], topic, party)[1], "x")
                if h.get("t") == kind and h.get("phase") == phase:
                    out.append(h)
        return out


def _kind(w, topic, payload, party):
    h, blobs = unpack(open_signed(payload, w["trust"], topic, party)[1], "x")
    return h, blobs


def test_a_leader_that_shows_the_helpers_two_coins_gets_no_verifier_share():
    """A1: the leader, running the broker, shows C another coin than B. Before the fix both helpers queried
    every proof, each at its own point, and sent their verifier shares: the leader solved every honest input
    exactly (L = 12 to 64)."""
    w = _world()
    A = w["params"].leader_id
    lead = _leader(w)
    other = bytes(range(32))
    psession = phase_session(session_id(7, 0), 1)

    def hook(topic, payload, rcpt):
        if topic.endswith(f"/agg/{A}") and rcpt == ("helper", C):
            h, blobs = _kind(w, topic, payload, A)
            if h.get("phase") == 1 and h["t"] in ("commit", "reveal"):
                blob = coin_commitment(psession, A, other) if h["t"] == "commit" else other
                return [seal(w["ka"].identity, topic, pack({k: v for k, v in h.items() if k != "blobs"}, blob))]
        return [payload]

    r = Router(w, lead, hook)
    r.session()
    assert lead.state == "aborted" and lead.result is None
    assert not r.sent(B, "vshares", 1) and not r.sent(C, "vshares", 1)
    for h in w["helpers"]:
        events = h.session((7, 0)).events
        assert any(k == "aborted" and "saw another phase" in why for k, why in events), events


def test_a_helper_that_shows_two_coins_by_timing_alone_is_caught():
    """A2: helper B, with an honest broker, holds back its phase-1 result from the leader so that C runs ahead,
    sends C a phase-3 coin early, then lets its own machine send the leader another. Before the fix the two
    holders of component 0 (which B lacks) queried every phase-3 proof at two points."""
    w = _world()
    lead = _leader(w)
    kb = w["keys"][B]
    held = []
    psession = phase_session(session_id(7, 0), 3)
    early = np.random.default_rng(4242).bytes(32)

    def hook(topic, payload, rcpt):
        if topic.endswith(f"/agg/{B}") and rcpt == ("leader", None):
            h, _ = _kind(w, topic, payload, B)
            if h.get("t") == "result" and h.get("phase") == 1:
                held.append((topic, payload))
                return []
        return [payload]

    r = Router(w, lead, hook)
    for p in lead.open(list(w["agents"])):
        r.publish(p.topic, p.payload)
    r.run()
    topic = lead.topics.agg(B)
    r.publish(topic, seal(kb.identity, topic, pack({"t": "commit", "phase": 3}, coin_commitment(psession, B, early))))
    r.publish(topic, seal(kb.identity, topic, pack({"t": "reveal", "phase": 3}, early)))
    r.run()
    for t, p in held:
        r.queue.append((("leader", None), t, p))
    r.run()
    for _ in range(3):
        if lead.done:
            break
        for p in lead.advance():
            r.publish(p.topic, p.payload)
        r.run()
    assert lead.state == "aborted" and lead.result is None
    assert not r.sent(w["params"].leader_id, "vshares", 3) and not r.sent(C, "vshares", 3)
    events = w["helpers"][1].session((7, 0)).events
    assert any(k == "aborted" and "aggregator-b sent two different 'commit' messages" in why for k, why in events)


def test_a_session_replayed_after_the_helpers_forgot_it_gets_no_second_coin():
    """A3: the leader makes the helpers forget a finished session (here: they remember none) and replays the
    vehicles' signed uploads to a new leader of the same measurement. Before the fix the helpers tossed new
    coins and sent verifier shares at a second point; only the release of the sums was refused."""
    w = _world()
    w["helpers"] = [PrioHelperService(PREFIX, w["params"], w["trust"], h.keys, h.log, max_finished=0)
                    for h in w["helpers"]]
    first = Router(w, _leader(w))
    first.session()
    assert first.lead.state == "finished" and all(h.finished == {} for h in w["helpers"])   # forgotten
    uploads = [(topic, payload) for kind, _, topic, payload in first.delivered if "/up/" in topic]
    second = Router(w, _leader(w))
    for p in second.lead.open(list(w["agents"])):
        if "/to/" not in p.topic:
            second.publish(p.topic, p.payload)
    for topic, payload in uploads:
        second.publish(topic, payload)
    second.run()
    for p in second.lead.advance():
        second.publish(p.topic, p.payload)
    second.run()
    assert second.lead.result is None
    for h in (B, C):
        assert not second.sent(h, "reveal", 1) and not second.sent(h, "vshares", 1)
        aborts = [h_ for h_ in second.sent(h, "abort", 1)]
        assert aborts and "already revealed" in aborts[0]["reason"]


def test_nothing_malformed_raises_out_of_a_party_and_a_vehicle_that_sends_it_is_named(monkeypatch):
    """A4: a deeply nested JSON header raised RecursionError and a 5,000-digit id ValueError out of every
    party's ``handle``; a vehicle that sealed such a share to a helper stalled the session without being named."""
    w = _world()
    lead = _leader(w)
    base = lead.topics.base
    nested = struct.pack("<I", len(DEEP)) + DEEP
    lead.open(list(w["agents"]))
    v1, kb = w["agents"]["v1"], w["keys"][B]
    assert v1.on_message(f"{base}/to/v1", nested) == [] and "not JSON" in v1.refusals[-1]
    assert lead.handle(f"{base}/up/v1", seal(v1.identity, f"{base}/up/v1", nested)) == []
    topic = f"{base}/agg/{B}"
    assert lead.handle(topic, seal(kb.identity, topic, nested)) == []
    digits = pack({"t": "vshares", "phase": 1, "ids": [1], "refused": {"9" * 5000: "x"}}, b"", b"")
    assert lead.handle(topic, seal(kb.identity, topic, digits)) == []
    for h in w["helpers"]:
        a_topic = f"{base}/agg/{w['params'].leader_id}"
        assert h.handle(a_topic, seal(w["ka"].identity, a_topic, nested)) == []
    # a vehicle seals a nested frame to helper B: it is refused and named, the session goes on without it
    honest = agent_mod.share_blob

    def evil(share, f):
        return nested if share.comps == (1, 2) and evil.pid == 3 else honest(share, f)
    submit = agent_mod.submit

    def tracking(enc, x, session, pid, rng, **kw):
        evil.pid = pid
        return submit(enc, x, session, pid, rng, **kw)
    monkeypatch.setattr(agent_mod, "share_blob", evil)
    monkeypatch.setattr(agent_mod, "submit", tracking)
    w = _world()
    lead = _leader(w)
    Router(w, lead).session()
    assert lead.state == "finished" and lead.accepted == (1, 2, 4, 5) and set(lead.refused) == {3}
    assert "malformed share" in lead.refused[3] or "not JSON" in lead.refused[3]


def test_a_protocol_id_of_two_to_the_32_raises_nowhere():
    """Round 2: a deviating leader put 2**32 as a protocol id in an invite, a roster and a close list; it reached
    ``int.to_bytes(4)`` and raised OverflowError out of a vehicle's and both helpers' ``handle`` (the vehicle had
    already spent its measurement). Ids and phases are now refused outside 1 to 2**31 - 1 wherever they are read."""
    from roadcollab.network.priowire import PrioTopics, share_blob
    from roadcollab.network.relaykey import seal_to
    from roadcollab.privacy.secagg_replicated import AggregatorShare

    big = 2 ** 32
    w = _world(n=3)
    t = PrioTopics(PREFIX, 7, 0)
    v1 = w["agents"]["v1"]
    invite = pack({"t": "invite", "phase": 1, "id": big, "roster": [1, 2, big]}, w["ka"].advert(PREFIX),
                  *[w["keys"][h].advert(PREFIX) for h in (B, C)], b"")
    assert v1.on_message(t.to("v1"), invite) == [] and "from 1 to 2147483647" in v1.refusals[-1]
    assert not v1.ledger.contributed(session_id(7, 0))                     # refused before anything is spent
    ka, svc = w["ka"], w["helpers"][0]
    at = t.agg(ka.party)
    svc.handle(at, seal(ka.identity, at, pack({"t": "open", "phase": 1, "roster": {"v2": big}})))
    share = AggregatorShare((1, 2), None, None, {1: b"s" * 16, 2: b"t" * 16}, {1: b"b" * 16, 2: b"c" * 16})
    sealed = seal_to(w["keys"][B].key.public, t.sealed_part(big, 1, B), share_blob(share, w["params"].wide.field))
    ft = t.fwd(B)
    body = pack({"t": "fwd", "phase": 1, "id": big}, sealed, b"\x00" * 192, w["agents"]["v2"].identity.certificate.to_bytes())
    assert svc.handle(ft, seal(ka.identity, ft, body)) == []
    events = svc.session((7, 0)).events
    assert any("protocol ids must be distinct integers from 1 to" in why for k, why in events if k == "refused")
    # the whole session, the roster and the close list carrying 2**32 to the helpers
    w = _world(n=3)
    lead = _leader(w)
    A = w["params"].leader_id

    def hook(topic, payload, rcpt):
        if topic.endswith(f"/agg/{A}") and rcpt[0] == "helper":
            h, blobs = _kind(w, topic, payload, A)
            head = {k: v for k, v in h.items() if k != "blobs"}
            if h["t"] == "open":
                head["roster"] = dict(head["roster"], v9=big)
            elif h["t"] == "close":
                head["ids"] = sorted(head["ids"] + [big])
            else:
                return [payload]
            return [seal(w["ka"].identity, topic, pack(head, *blobs))]
        return [payload]

    r = Router(w, lead, hook)
    r.session()                                   # nothing raises: the helpers refuse the open
    assert lead.state == "aborted" and lead.result is None


def test_another_helpers_early_messages_are_held_within_a_byte_budget(monkeypatch):
    """A deviating helper floods signed messages for sessions the leader never opens: before the byte cap,
    16 x 1,024 of them were held whatever their size (up to MAX_MESSAGE_BYTES each, tens of MB)."""
    import roadcollab.network.priohelper as helper_mod
    monkeypatch.setattr(helper_mod, "MAX_EARLY_PEER_BYTES", 200_000)
    w = _world()
    svc = w["helpers"][0]
    ident = w["keys"][C].identity
    for s in range(1, 40):
        topic = f"{PREFIX}/prio/{s}/0/agg/{C}"
        for _ in range(3):
            svc.handle(topic, seal(ident, topic, pack({"t": "commit", "phase": 1}, bytes(20_000))))
    held = sum(len(p) for msgs in svc._early.values() for _, p in msgs)
    assert held == svc._early_bytes <= 200_000 and held > 150_000          # the newest sessions kept
    assert (39, 0) in svc._early and (1, 0) not in svc._early
    topic = f"{PREFIX}/prio/99/0/agg/{C}"
    svc.handle(topic, seal(ident, topic, pack({"t": "commit", "phase": 1}, bytes(300_000))))   # larger than all
    assert (99, 0) not in svc._early and svc._early_bytes == held


def test_a_leaders_early_forwarded_uploads_are_held_within_a_byte_budget(monkeypatch):
    """Uploads the leader forwards before a helper has the session's roster: capped in bytes, not only count."""
    import roadcollab.network.priohelper as helper_mod
    from roadcollab.errors import MessageError
    from roadcollab.network.priohelper import PrioHelper
    monkeypatch.setattr(helper_mod, "MAX_EARLY_BYTES", 100_000)
    w = _world()
    h = PrioHelper(PREFIX, 7, 0, w["params"], w["trust"], w["keys"][B], w["helpers"][0].log, np.random.default_rng(0))
    topic = f"{PREFIX}/prio/7/0/fwd/{B}"
    ident = w["keys"]["aggregator-a"].identity
    big = seal(ident, topic, pack({"t": "fwd", "id": 1, "phase": 1}, bytes(40_000), b"", b""))
    h._forwarded(topic, big)
    h._forwarded(topic, big)
    try:
        h._forwarded(topic, big)
    except MessageError as err:
        assert "bytes" in str(err)
    else:
        raise AssertionError("a third 40 kB forwarded upload was kept under a 100 kB budget")
    assert len(h._early) == 2
