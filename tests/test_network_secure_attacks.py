"""An attacking roadside service against the real, unmodified ``roadcollab vehicle`` processes over the
embedded broker on 127.0.0.1 (issue 20: "the secure aggregation runs between separate processes over the
broker, with the same rows measured there").

The service runs in the test process: the project's :class:`~roadcollab.network.service.Service` and
:class:`~roadcollab.network.rounds.SecureRounds` with the deviating coordinators of
:mod:`roadcollab.network.secround_attacks` (the service routes every message, so it may deviate at every
step). The victim is ``v1``; four vehicle processes drive six 100 m segments, so each attack gets six
tries (one per segment). Success criteria as in :func:`~roadcollab.network.secround_attacks.network_attack`:

- ``differencing``: after the honest round of a segment (closed notices withheld, so the vehicles stay),
  a second round on that segment without ``v1``; success if it finishes (its sum subtracted from the
  first gives ``v1``'s input);
- ``equivocation``: ``U_3`` with ``v1`` to ``v1`` and half the others, without it to the rest; success if
  the reveals hold ``t`` shares of ``v1``'s ``b`` and ``t`` of its ``s_sk`` and its masked input arrived;
- ``sybil``: ``v1`` with ``k - 1`` ids the service plays (adverts signed by an authority of its own);
  success if ``v1`` sends its masked input;
- ``key_substitution``: the roster shown to ``v1`` carries the service's keys for every other vehicle;
  success if ``v1`` deals it shares.

Every attack must succeed on none of the six segments (0 %, target <= 5 %); ``v1``'s ledger records a
masked input only where the round was honest up to that point (``differencing``'s first round,
``equivocation`` before ``U_3``).
"""

import shutil
import threading

import numpy as np
import pytest
from netkit import free_port, rc, start_amqtt, stop, write_drives

from roadcollab.experiments.security.secagg_attacks import _fake_adverts
from roadcollab.io.drives import load_drives
from roadcollab.network.fleetdir import load_aggregation, load_login, load_plan, load_trust
from roadcollab.network.mqtt_client import MqttClient
from roadcollab.network.mqtt_run import run_service
from roadcollab.network.rounds import SecureRounds
from roadcollab.network.secround import RoundCoordinator, _b64
from roadcollab.network.secround_attacks import _Equivocate, _Substitute, _Sybil
from roadcollab.network.service import Service
from roadcollab.network.store import ServiceStore
from roadcollab.privacy.secagg_messages import session_id
from roadcollab.privacy.secagg_store import SessionLedger
from roadcollab.wire.protocol import decode
from roadcollab.wire.secagg import Reveal

pytestmark = pytest.mark.slow

ATTACKS = ("differencing", "equivocation", "sybil", "key_substitution")


class _Withhold(RoundCoordinator):
    """An honest round whose closed notices are withheld (the vehicles stay for the second round)."""

    def _closed(self, outcome, reason):
        return []


class _AttackRounds(SecureRounds):
    attack = ""

    def __init__(self, *a, **kw):
        self.ended: list[RoundCoordinator] = []
        self.gen = np.random.default_rng(7)
        super().__init__(*a, **kw)

    def maybe_open(self, segment):
        if self.attack != "sybil":
            return super().maybe_open(segment)
        if any(k[0] == segment for k in self.active) or any(r["segment"] == segment for r in self.store.rounds()):
            return []
        if "v1" not in [v for v, _ in self.store.contributors(segment)]:
            return []
        return self.open_round((segment, 0), ["v1"] + [f"sybil{i}" for i in range(2, self.spec.min_inputs + 1)])

    def open_round(self, key, roster):
        out = super().open_round(key, roster)
        co = self.active[key]
        if self.attack in ("sybil", "key_substitution"):
            hi = self.spec.min_inputs + 1 if self.attack == "sybil" else len(roster) + 1
            _, fakes = _fake_adverts(range(2, hi), session_id(*key), self.gen)
            co.fakes = fakes if self.attack == "sybil" else {i: _b64(d) for i, d in fakes.items()}
        return out

    def _close(self, key, co):
        self.ended.append(co)
        out = super()._close(key, co)
        if self.attack == "differencing" and key[1] == 0 and co.phase == "finished":
            out += self.open_round((key[0], 1), [v for v in co.roster if v != "v1"])
        return out


_COORDINATOR = {"differencing": _Withhold, "equivocation": _Equivocate, "sybil": _Sybil,
                "key_substitution": _Substitute}


def _succeeded(attack, co, t):
    if attack == "differencing":
        return co.epoch == 1 and co.phase == "finished"
    v1 = co.pid.get("v1")
    if attack == "equivocation":
        reveals = [r for r in (decode(b) for b in co.got["reveal"].values()) if isinstance(r, Reveal)]
        b = sum(v1 in r.self_mask_shares for r in reveals)
        s = sum(v1 in r.key_shares for r in reveals)
        return v1 in co.got["masked"] and b >= t and s >= t
    if attack == "sybil":
        return v1 in co.got["masked"]
    return v1 in co.got["shares"]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("secatk")
    drives, _ = write_drives(root / "drives")
    vmin = min(float(d.speeds().min()) for d in load_drives(drives))
    rc("enroll", "--fleet", root / "fleet", "--vehicles", 4, "--fleet-id", "t", "--min-speed", repr(vmin),
       "--aggregation", "secure", "--min-inputs", 3, "--threshold", 3, "--round-size", 4)
    return root, drives


@pytest.mark.parametrize("attack", ATTACKS)
def test_an_attacking_service_gets_nothing_from_real_vehicles(world, tmp_path, attack):
    root, drives = world
    fleet = tmp_path / "fleet"
    shutil.copytree(root / "fleet", fleet)
    policy, trust = load_aggregation(fleet), load_trust(fleet)
    port = free_port()
    broker = start_amqtt(fleet, port, tmp_path / "broker.log")
    _AttackRounds.attack = attack
    held: dict = {}
    stop_ev, republish, ready = threading.Event(), threading.Event(), threading.Event()

    def serve():       # the store is SQLite: opened, used and closed in this one thread
        store = ServiceStore(tmp_path / "s.sqlite", load_plan(fleet))
        rounds = _AttackRounds(store, trust, policy, "rc/t", phase_timeout_s=3.0, round_wait_s=1e9,
                               coordinator=_COORDINATOR[attack])
        service = Service(store, trust, rounds=rounds)
        client = MqttClient(f"mqtt://127.0.0.1:{port}", load_login(fleet / "service" / "broker.toml"),
                            "rc-attacker", on_connect=republish.set)
        for f in service.subscriptions:
            client.subscribe(f)
        client.connect()
        held["rounds"] = rounds
        ready.set()
        try:
            run_service(service, client, stop_ev, republish)
        finally:
            client.close()
            store.close()

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    assert ready.wait(60)
    try:
        out = rc("fleet", "--fleet", fleet, *sum((["--drive", d] for d in drives), []), "--broker",
                 f"mqtt://127.0.0.1:{port}", "--timeout", 45, timeout=240, check=False)
    finally:
        stop_ev.set()
        th.join(30)
        stop(broker)
    rounds = held["rounds"]
    ended = rounds.ended + list(rounds.active.values())
    assert ended, out.stdout                                   # the attack was tried
    segments = {co.segment for co in ended}
    assert len(segments) == 6, segments
    wins = [co.segment for co in ended if _succeeded(attack, co, policy.threshold)]
    assert wins == [], f"{attack} recovered v1's input on segments {wins}"
    ledger = SessionLedger(fleet / "vehicles" / "v1" / "secagg_ledger.sqlite")
    gave = [(s, e) for s in segments for e in range(3) if ledger.contributed(session_id(s, e))]
    # v1 sends its masked input in the rounds that are honest up to that point (differencing's first round,
    # equivocation before U_3); the Sybil and substituted rosters fail its roster check before any share.
    assert gave == ([(s, 0) for s in sorted(segments)] if attack in ("differencing", "equivocation") else []), gave
    if attack == "differencing":                               # the second rounds got no advert at all
        second = [co for co in ended if co.epoch == 1]
        assert len(second) == 6 and all(not co.got["adverts"] for co in second)
