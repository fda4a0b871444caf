"""A malicious roadside service against honest networked vehicles: the four attacks of issue 20 on
:mod:`roadcollab.network.secround`'s state machines, over the in-memory broker.

Each attack runs a :class:`~roadcollab.network.secround.RoundCoordinator` subclass (the service deviating
as it likes: it routes every message) against honest :class:`~roadcollab.network.secround.RoundAgent`
vehicles, and returns the victim's input as the service recovers it, or None when it got nothing about
the victim beyond an honest aggregate:

- ``differencing``: a finished round with every vehicle, then a second round on the same (segment,
  epoch) without the victim; recovered = ``n avg_1 - (n - 1) avg_2`` if the second finishes.
- ``equivocation``: ``U_3`` told with the victim to the victim and half the others, without it to the
  rest; recovered (exactly, see :func:`roadcollab.experiments.security.secagg_attacks.active_attack`) if the
  reveals hold ``t`` shares of the victim's ``b`` and ``t`` of its ``s_sk``.
- ``sybil``: the victim and ``k - 1`` ids the service plays (adverts signed by identities of an
  authority of its own); recovered if the victim sends ``y`` in that roster (the service holds every
  other key, so the victim's masks are its own).
- ``key_substitution``: the roster shown to the victim carries the service's keys (signed by its own
  authority) for every other vehicle; recovered if the victim deals shares to it (its ``b`` shares and
  every pairwise seed are then the service's).
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..experiments.security.secagg_attacks import _fake_adverts
from ..privacy.secagg_messages import SecAggSpec, session_id
from ..privacy.secagg_store import SessionLedger
from ..wire.identity import FleetAuthority, VehicleIdentity
from ..wire.protocol import decode
from ..wire.secagg import Reveal
from .secround import RoundCoordinator, _b64
from .secround_agent import RoundAgent, clip_mean, run_round

__all__ = ["NETWORK_ATTACKS", "network_attack", "network_attack_study"]

NETWORK_ATTACKS = ("differencing", "equivocation", "sybil", "key_substitution")
_KEY = (0, 0)


class _Equivocate(RoundCoordinator):
    victim = "v1"

    def relay_survivors(self, vid, survivors):
        half = sorted(self.pid)[len(self.pid) // 2 + 1:]
        return [i for i in survivors if i != self.pid[self.victim]] if vid in half else survivors


class _Substitute(RoundCoordinator):
    fakes: dict = {}

    def relay_roster(self, vid, signed):
        if vid != "v1":
            return signed
        return {k: (v if k == "1" else self.fakes[int(k)]) for k, v in signed.items()}


class _Sybil(RoundCoordinator):
    fakes: dict = {}

    def advance(self):
        if self.phase == "adverts":
            for i, data in self.fakes.items():
                self.got["adverts"][i] = data
        return super().advance()


def network_attack(attack: str, zs, spec: SecAggSpec, *, rng=None, keep_ledgers: bool = True):
    """Run ``attack`` against vehicles ``v1..vn`` (``v1`` the victim) with inputs ``zs``.

    Parameters
    ----------
    attack : str
        One of :data:`NETWORK_ATTACKS`.
    zs : sequence of (L, 2) array_like
        ``zs[i]`` is vehicle ``v{i+1}``'s ``z`` of segment 0, epoch 0, m/s.
    spec : SecAggSpec
    rng : None, int or Generator
        Session secrets and the service's fake keys.
    keep_ledgers : bool
        ``differencing`` only: False gives the restarted vehicles empty ledgers (a vehicle that lost its
        record), which shows the harness recovering the victim when the ledger is missing.

    Returns
    -------
    recovered : (L, 2) ndarray or None
    coordinator : RoundCoordinator
        The (last) round, with its ``events``.
    agents : dict of str to RoundAgent
    """
    if attack not in NETWORK_ATTACKS:
        raise ParameterError(f"attack must be one of {', '.join(NETWORK_ATTACKS)}, got {attack!r}")
    gen = np.random.default_rng(rng)
    auth = FleetAuthority.generate("f")
    trust = auth.trust()
    n = len(zs)
    agents = {f"v{i + 1}": RoundAgent(VehicleIdentity.enroll(auth, f"v{i + 1}"), trust, spec, SessionLedger(), "f",
                                      {_KEY: np.asarray(zs[i], float)}, root=lambda s, e: gen.bytes(32))
              for i in range(n)}
    victim_z = np.clip(np.asarray(zs[0], float), -spec.clip, spec.clip)
    session = session_id(*_KEY)
    if attack == "differencing":
        first = RoundCoordinator("f", *_KEY, spec, trust)
        run_round(first, agents, list(agents))
        second = RoundCoordinator("f", *_KEY, spec, trust)
        # restarted vehicles (fresh agents, their persisted ledgers): only the ledger stands in the way
        again = {v: RoundAgent(a.identity, trust, spec, a.ledger if keep_ledgers else SessionLedger(), "f", a.inputs, root=lambda s, e: gen.bytes(32))
                 for v, a in agents.items() if v != "v1"}
        run_round(second, again, list(again))
        if first.average is None or second.average is None:
            return None, second, agents
        return n * first.average - (n - 1) * second.average, second, agents
    if attack == "equivocation":
        co = _Equivocate("f", *_KEY, spec, trust)
        run_round(co, agents, list(agents))
        reveals = [r for r in (decode(b) for b in co.got["reveal"].values()) if isinstance(r, Reveal)]
        b = sum(1 in r.self_mask_shares for r in reveals)
        s = sum(1 in r.key_shares for r in reveals)
        got = 1 in co.got["masked"] and b >= spec.threshold and s >= spec.threshold
        return (victim_z if got else None), co, agents
    _, fakes = _fake_adverts(range(2, spec.min_inputs + 1 if attack == "sybil" else n + 1), session, gen)
    if attack == "sybil":
        sy = _Sybil("f", *_KEY, spec, trust)
        sy.fakes = fakes
        run_round(sy, {"v1": agents["v1"]}, ["v1"] + [f"sybil{i}" for i in range(2, spec.min_inputs + 1)])
        return (victim_z if 1 in sy.got["masked"] else None), sy, agents
    ks = _Substitute("f", *_KEY, spec, trust)
    ks.fakes = {i: _b64(d) for i, d in fakes.items()}
    run_round(ks, agents, list(agents))
    return (victim_z if 1 in ks.got["shares"] else None), ks, agents


def network_attack_study(trials: int, n: int = 9, *, length: int = 64, rng=None) -> list[dict]:
    """Success rate and the service's error on the victim's input, per attack.

    The error of one trial is ``||guess - z_1|| / ||z_1||`` (relative RMS, victim's clipped input),
    where ``guess`` is the recovered input or, when the attack got nothing, the best the service
    has: the honest average of all ``n`` inputs.

    Parameters
    ----------
    trials : int
        Trials per attack (fresh fleet, fresh road inputs ``z ~ N(0, 0.5^2)`` m/s).
    n : int
        Vehicles (``k = t = 5``, ``c = 0``: rosters up to ``2t - 1 = 9``).
    length : int
        Rows of ``z``.
    rng : None, int or Generator

    Returns
    -------
    list of dict
        ``attack``, ``trials``, ``success`` (fraction), ``median_error``.
    """
    gen = np.random.default_rng(rng)
    spec = SecAggSpec(min_inputs=5, threshold=5, max_colluders=0)
    rows = []
    for attack in NETWORK_ATTACKS:
        wins, errs = 0, []
        for _ in range(int(trials)):
            zs = list(gen.normal(0.0, 0.5, (n, length, 2)))
            got, _, _ = network_attack(attack, zs, spec, rng=gen)
            z1 = np.clip(zs[0], -spec.clip, spec.clip)
            guess = clip_mean(zs, spec) if got is None else got
            err = float(np.linalg.norm(guess - z1) / np.linalg.norm(z1))
            wins += err < 1e-6
            errs.append(err)
        rows.append({"attack": attack, "trials": int(trials), "success": wins / int(trials),
                     "median_error": float(np.median(errs))})
    return rows
