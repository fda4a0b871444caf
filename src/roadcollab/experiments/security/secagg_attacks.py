"""An active aggregator attacking secure aggregation: each attack against the semi-honest and the active protocol.

Every attack returns the victim's input as the aggregator recovers it (m/s, (L, 2)), or None when the
protocol gave it nothing about the victim beyond an honest aggregate. The aggregator acts alone (no
colluding vehicle) unless stated:

- ``differencing``: two sessions on one measurement (segment, epoch), with and without the victim;
  the difference of the aggregates is the victim's ``z`` (no deviation from the semi-honest protocol).
- ``equivocation``: the victim and 4 others are told "victim survived", the other 5 "victim dropped";
  the first group's shares of ``b`` and the second's of ``s_sk`` unmask ``y_victim``.
- ``double_reveal``: every vehicle is asked to reveal twice, for two survivor sets.
- ``sybil``: the victim plus invented vehicles the aggregator plays (inputs it knows) fill ``k``.
- ``key_substitution``: the roster sent to the victim carries the aggregator's keys for everyone else;
  it opens the victim's sealed shares (``b``) and knows every pairwise mask.
"""

from __future__ import annotations

import numpy as np

from ...errors import MessageError
from ...privacy._secagg_kernels import decode_sum, derive, prg_ring, shamir_combine
from ...privacy.secagg_active_run import Relay, SecAggFleet, run_active_session
from ...privacy.secagg_messages import SecAggSpec, session_id
from ...privacy.secagg_run import run_secure_aggregation
from ...privacy.secure_aggregation import (_open_share, _pair_mask, advertise_keys, mask_input, reveal_shares,
                                           share_keys)
from ...wire.identity import FleetAuthority, VehicleIdentity
from ...wire.secagg_signed import sign_advert
from .rows import AttackRow, attack_row

__all__ = ["SECAGG_ATTACKS", "STUDY_ATTACKS", "active_spec", "legacy_attack", "active_attack", "secagg_attack_rows"]

SECAGG_ATTACKS = ("differencing", "equivocation", "double_reveal", "sybil", "key_substitution")


def active_spec(n: int) -> SecAggSpec:
    """The active protocol's parameters for ``n`` vehicles: ``c = floor((n - 1) / 3)``, ``t = k = floor((n + c) / 2) + 1``.

    So ``c < n / 3`` and ``2t > n + c`` (Bonawitz et al.'s ``t > 2n / 3``); ``n = 10`` gives ``c = 3, t = 7``.

    Parameters
    ----------
    n : int
        Vehicles in the roster.

    Returns
    -------
    SecAggSpec
    """
    c = (n - 1) // 3
    t = (n + c) // 2 + 1
    return SecAggSpec(min_inputs=t, threshold=t, max_colluders=c)


def _strip(y, b_seed: bytes, s_sk: bytes, victim: int, s_pks: dict, session: bytes, frac_bits: int) -> np.ndarray:
    """``x_victim`` from ``y_victim``, its ``b`` and its ``s_sk`` (every pairwise mask with ``s_pks``), m/s."""
    x = y - prg_ring(derive(b_seed, b"self", session, victim), y.shape)
    for j, pk in s_pks.items():
        if j != victim:
            x = x - _pair_mask(s_sk, victim, j, pk, session, y.shape)
    return decode_sum(x, frac_bits)


def _legacy_session(zs: dict, spec: SecAggSpec, session: bytes, gen):
    secrets, roster = {}, {}
    for i in sorted(zs):
        secrets[i], roster[i] = advertise_keys(i, session, root=gen.bytes(32))
    sealed = {}
    for i in sorted(zs):
        sealed.update({(i, j): c for j, c in share_keys(secrets[i], roster, spec).items()})
    masked = {i: mask_input(secrets[i], zs[i], roster, spec) for i in sorted(zs)}
    return secrets, roster, sealed, masked


def legacy_attack(attack: str, inputs, victim: int, spec: SecAggSpec = SecAggSpec(), *, rng=None) -> np.ndarray | None:
    """Run ``attack`` against the semi-honest protocol (:mod:`roadcollab.privacy.secure_aggregation`).

    Parameters
    ----------
    attack : str
        One of :data:`SECAGG_ATTACKS`.
    inputs : sequence of (L, 2) array_like
        Vehicle ``i``'s ``z`` is ``inputs[i - 1]``, m/s.
    victim : int
        Protocol id of the victim.
    spec : SecAggSpec
    rng : None, int or Generator
        Session secrets (reproducible).

    Returns
    -------
    (L, 2) ndarray or None
        The victim's (clipped, quantised) input as recovered.
    """
    gen = np.random.default_rng(rng)
    zs = {i + 1: np.asarray(z, float) for i, z in enumerate(inputs)}
    ids, session = sorted(zs), session_id(0, 0)
    if attack == "differencing":
        full = run_secure_aggregation([zs[i] for i in ids], spec, rng=gen)
        rest = run_secure_aggregation([zs[i] for i in ids if i != victim], spec, rng=gen)
        return full.result.total - rest.result.total
    if attack == "sybil":
        fakes = [np.zeros_like(zs[victim]) for _ in range(spec.min_inputs - 1)]  # the aggregator's own inputs
        return run_secure_aggregation([zs[victim], *fakes], spec, rng=gen).result.total
    if attack == "key_substitution":
        secrets, roster = {}, {}
        for i in ids:           # the aggregator generates every key but the victim's
            secrets[i], roster[i] = advertise_keys(i, session, root=gen.bytes(32))
        sealed = share_keys(secrets[victim], roster, spec)
        y = mask_input(secrets[victim], zs[victim], roster, spec).y
        b = {j: _open_share(secrets[j], victim, sealed[j], roster)[1] for j in ids if j != victim}
        b_seed = shamir_combine(dict(list(b.items())[:spec.threshold]), spec.threshold, "b")
        x = y - prg_ring(derive(b_seed, b"self", session, victim), y.shape)
        for j in ids:
            if j != victim:     # the aggregator holds s_sk_j: X25519(s_sk_j, s_pk_victim) is the victim's seed
                x = x - _pair_mask(secrets[j].s_sk, victim, j, roster[victim].s_pk, session, y.shape)
        return decode_sum(x, spec.frac_bits)
    if attack not in ("equivocation", "double_reveal"):
        raise MessageError(f"attack must be one of {SECAGG_ATTACKS}, got {attack!r}")
    secrets, roster, sealed, masked = _legacy_session(zs, spec, session, gen)
    others = [i for i in ids if i != victim]
    told_alive = [victim, *others[:len(ids) // 2 - 1]] if attack == "equivocation" else ids
    told_dropped = others[len(ids) // 2 - 1:] if attack == "equivocation" else ids
    b, s = {}, {}
    for j in told_alive:
        mine = {i: sealed[(i, j)] for i in ids if i != j}
        b[j] = reveal_shares(secrets[j], mine, roster, ids, spec).self_mask_shares[victim]
    for j in told_dropped:
        mine = {i: sealed[(i, j)] for i in ids if i != j}
        if j != victim:
            s[j] = reveal_shares(secrets[j], mine, roster, others, spec).key_shares[victim]
    b_seed = shamir_combine(b, spec.threshold, "b of the victim")
    s_sk = shamir_combine(s, spec.threshold, "s_sk of the victim")
    return _strip(masked[victim].y, b_seed, s_sk, victim, {i: a.s_pk for i, a in roster.items()}, session,
                  spec.frac_bits)


class _Equivocate(Relay):
    """Shows the survivor set with the victim to ``alive`` and without it to everyone else."""

    def __init__(self, victim: int, alive) -> None:
        self.victim, self.alive = victim, set(alive)

    def survivors(self, recipient: int, survivors: list) -> list:
        return survivors if recipient in self.alive else [i for i in survivors if i != self.victim]


class _Substitute(Relay):
    """Sends ``victim`` a roster whose other entries are ``fakes`` (adverts the aggregator made and signed)."""

    def __init__(self, victim: int, fakes: dict) -> None:
        self.victim, self.fakes = victim, fakes

    def roster(self, recipient: int, signed: dict) -> dict:
        return {**signed, **self.fakes} if recipient == self.victim else signed


def _fake_adverts(ids, session: bytes, gen, authority: FleetAuthority | None = None) -> tuple[dict, dict]:
    """Adverts for ``ids`` with the aggregator's keys, signed by identities of its own authority."""
    authority = authority or FleetAuthority.generate("fleet")     # same fleet name, not the fleet's key
    secrets, signed = {}, {}
    for j in ids:
        secrets[j], adv = advertise_keys(j, session, root=gen.bytes(32))
        signed[j] = sign_advert(VehicleIdentity.enroll(authority, f"veh-{j}"), adv)
    return secrets, signed


def _recover(run, victim: int, spec: SecAggSpec, session: bytes, s_pks: dict) -> np.ndarray | None:
    """The victim's input if the reveals the aggregator got hold ``t`` shares of its ``b`` and of its ``s_sk``."""
    b = {r.vehicle: r.self_mask_shares[victim] for r in run.reveals if victim in r.self_mask_shares}
    s = {r.vehicle: r.key_shares[victim] for r in run.reveals if victim in r.key_shares}
    if victim not in run.masked or len(b) < spec.threshold or len(s) < spec.threshold:
        return None
    b_seed, s_sk = shamir_combine(b, spec.threshold, "b"), shamir_combine(s, spec.threshold, "s_sk")
    return _strip(run.masked[victim].y, b_seed, s_sk, victim, s_pks, session, spec.frac_bits)


def active_attack(attack: str, inputs, victim: int, spec: SecAggSpec | None = None, *, segment: int = 0,
                  rng=None) -> tuple[np.ndarray | None, dict]:
    """Run ``attack`` against the active protocol (:mod:`roadcollab.privacy.secagg_active`), fresh fleet.

    Parameters
    ----------
    attack : str
        One of :data:`SECAGG_ATTACKS`.
    inputs : sequence of (L, 2) array_like
        Vehicle ``i``'s ``z`` is ``inputs[i - 1]``, m/s.
    victim : int
    spec : SecAggSpec, optional
        Default :func:`active_spec` of the fleet size.
    segment : int
        The measurement's segment (epoch 0).
    rng : None, int or Generator

    Returns
    -------
    recovered : (L, 2) ndarray or None
    refusals : dict
        Why each vehicle stopped: vehicle id -> message (``differencing``: keyed by (session label, id)).
    """
    gen = np.random.default_rng(rng)
    n = len(inputs)
    spec = spec or active_spec(n)
    fleet = SecAggFleet(n, spec)
    zs = {i + 1: np.asarray(z, float) for i, z in enumerate(inputs)}
    session = session_id(segment, 0)
    others = [i for i in sorted(zs) if i != victim]
    if attack == "differencing":
        full = run_active_session(fleet, zs, session, rng=gen)
        second = {i: zs[i] for i in others}
        rest = run_active_session(fleet, second, session, rng=gen)              # the same (segment, epoch)
        relabelled = run_active_session(fleet, second, session_id(segment, 1), measured=(segment, 0), rng=gen)
        runs = (("first", full), ("second", rest), ("relabelled", relabelled))
        by_run: dict[tuple[str, int], str] = {(label, i): why for label, r in runs for i, why in r.refusals.items()}
        got = [r.aggregate for r in (rest, relabelled) if r.aggregate is not None]
        if full.aggregate is None or not got:
            return None, by_run
        return full.aggregate.result.total - got[0].result.total, by_run
    if attack in ("equivocation", "double_reveal"):
        alive = [victim, *others[:n // 2 - 1]]
        run = run_active_session(fleet, zs, session, relay=_Equivocate(victim, alive), rng=gen)
        refusals = dict(run.refusals)
        if attack == "double_reveal":   # then ask every vehicle to sign the other set as well
            for i, v in fleet.vehicles.items():
                try:
                    v.sign_survivors(others if i in alive else sorted(zs))
                except MessageError as err:
                    refusals[i] = f"{type(err).__name__}: {err}"
        roster = fleet.vehicles[victim]._roster
        adverts = roster.adverts if roster is not None else {}
        return _recover(run, victim, spec, session, {i: a.s_pk for i, a in adverts.items()}), refusals
    # Sybil and key substitution: a victim that accepted the forged roster would be exposed exactly (the
    # aggregator holds every other key; legacy_attack shows the recovery), so acceptance counts as recovery.
    if attack == "sybil":
        _, signed = _fake_adverts(range(n + 1, n + spec.min_inputs), session, gen)
        run = run_active_session(fleet, {victim: zs[victim]}, session, relay=_Substitute(victim, signed), rng=gen)
        return (None if victim in run.refusals else zs[victim]), run.refusals
    if attack == "key_substitution":
        _, signed = _fake_adverts(others, session, gen)
        run = run_active_session(fleet, zs, session, relay=_Substitute(victim, signed), rng=gen)
        return (None if victim in run.refusals else zs[victim]), run.refusals
    raise MessageError(f"attack must be one of {SECAGG_ATTACKS}, got {attack!r}")


#: The attacks of ``attack.csv`` (``double_reveal`` is the per-vehicle form of ``equivocation``: tests only).
STUDY_ATTACKS = ("differencing", "equivocation", "sybil", "key_substitution")


def secagg_attack_rows(segs: list, n_targets: int, aggregate_errors: list, fit, seed: int) -> list[AttackRow]:
    """``attack.csv`` rows of the active aggregator against the active protocol, one per attack.

    For each segment and target vehicle the attack runs on the fleet's ``z``. What the aggregator then
    fits the replica to is the victim's input if the attack recovered it, otherwise the most it can
    get: an honest session's aggregate (the ``secure_aggregation`` / ``replica`` cell, whose errors are
    reused).

    Parameters
    ----------
    segs : list of dict
        The replica study's segments (``z_all`` (n, nfft, 2), ``road``).
    n_targets : int
        Vehicles attacked (the first ones).
    aggregate_errors : list of ndarray
        Pole errors of the replica fit on the aggregate, per (segment, target) in that order.
    fit : callable
        ``fit(z, road, j) -> pole errors`` of a replica fit on a recovered input.
    seed : int
        Root of the session secrets.

    Returns
    -------
    list of AttackRow
    """
    rows = []
    for a, attack in enumerate(STUDY_ATTACKS):
        errs = []
        for r, s in enumerate(segs):
            for j in range(n_targets):
                got, _ = active_attack(attack, list(s["z_all"]), j + 1, segment=r, rng=[seed, a, r, j])
                errs.append(aggregate_errors[r * n_targets + j] if got is None else fit(got, s["road"]["true"][j], j))
        rows.append(attack_row("secure_aggregation", attack, "true", 1, errs))
    return rows
