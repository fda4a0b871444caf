"""The active protocol of :mod:`.secagg_active` simulated end to end, with an aggregator that may deviate.

:func:`run_active_session` plays the certified vehicles and the aggregator in-process and relays every
message through the :class:`Relay` hooks, which an attack overrides (an honest relay forwards everything
unchanged). :class:`SecAggFleet` holds what exists before any session: the fleet authority, one certified
identity and one :class:`~.secagg_store.SessionLedger` per vehicle. The network transport of the
networked fleet calls the same :class:`~.secagg_active.SecAggVehicle` methods.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from .._validation import check_int
from ..errors import MessageError
from ..wire.identity import FleetAuthority, FleetTrust, VehicleIdentity
from ..wire.secagg import MaskedInput, Reveal
from ._secagg_kernels import KEY_NBYTES
from .secagg_active import SecAggVehicle, VerifiedAggregate, unmask_verified, verify_roster
from .secagg_messages import SecAggSpec
from .secagg_store import SessionLedger

__all__ = ["SecAggFleet", "Relay", "ActiveRun", "run_active_session"]

ROUNDS = ("advertise_keys", "share_keys", "masked_input", "consistency", "unmasking")


@dataclass(eq=False)
class SecAggFleet:
    """Certified vehicles ``1..n`` of one fleet, each with its ledger (in memory unless ``folder`` is set).

    Parameters
    ----------
    n : int
        Vehicles.
    spec : SecAggSpec
    ledger_paths : sequence of path-like, optional
        One SQLite ledger per vehicle (persisted); default in memory.
    """

    n: int
    spec: SecAggSpec
    ledger_paths: tuple[str, ...] = ()
    authority: FleetAuthority = field(init=False)
    vehicles: dict[int, SecAggVehicle] = field(init=False)

    def __post_init__(self) -> None:
        check_int("n", self.n, low=1)
        self.authority = FleetAuthority.generate("fleet")
        paths: tuple[str | None, ...] = tuple(self.ledger_paths) or (None,) * self.n
        self.vehicles = {i: SecAggVehicle(i, VehicleIdentity.enroll(self.authority, f"veh-{i}"),
                                          self.authority.trust(), self.spec, SessionLedger(paths[i - 1]))
                         for i in range(1, self.n + 1)}

    @property
    def trust(self) -> FleetTrust:
        """The fleet's trust anchor."""
        return self.authority.trust()


class Relay:
    """The aggregator's relaying: honest by default; an attack overrides a hook.

    Every hook receives what an honest aggregator would send to ``recipient`` and returns what it sends.
    """

    def roster(self, recipient: int, signed: dict[int, bytes]) -> dict[int, bytes]:
        return signed

    def survivors(self, recipient: int, survivors: list[int]) -> list[int]:
        return survivors

    def signatures(self, recipient: int, signatures: dict[int, bytes]) -> dict[int, bytes]:
        return signatures


@dataclass(frozen=True)
class ActiveRun:
    """One active session: the aggregate (or None if refused), what each vehicle refused, cost.

    Attributes
    ----------
    aggregate : VerifiedAggregate or None
    refusals : dict of int to str
        Vehicle id -> the reason it stopped (message of the exception it raised).
    reveals : tuple of Reveal
        What the aggregator received in round 3.
    masked : dict of int to MaskedInput
    vehicle_ms : (n, 5) ndarray
        Wall-clock ms per vehicle and round (:data:`ROUNDS`).
    bytes_sent : (n, 5) ndarray of int
    aggregator_ms : float
        Wall-clock ms of :func:`~.secagg_active.unmask_verified` (0 if not reached).
    """

    aggregate: VerifiedAggregate | None
    refusals: dict[int, str]
    reveals: tuple[Reveal, ...]
    masked: dict[int, MaskedInput]
    vehicle_ms: np.ndarray
    bytes_sent: np.ndarray
    aggregator_ms: float = 0.0


_T = TypeVar("_T")
_Rng = int | np.random.Generator | None


def _try(refusals: dict[int, str], i: int, fn: Callable[..., _T], *args: Any) -> _T | None:
    try:
        return fn(*args)
    except MessageError as err:     # AggregationRefused included: the vehicle stops, nothing is sent
        refusals[i] = f"{type(err).__name__}: {err}"
        return None


def run_active_session(fleet: SecAggFleet, inputs: dict[int, Any], session: bytes, *,
                       measured: tuple[int, int] | None = None, relay: Relay | None = None,
                       dropped_before_masking: Iterable[int] = (), silent_in_unmasking: Iterable[int] = (),
                       corrupt: Callable[[Reveal], Reveal] | None = None, rng: _Rng = None) -> ActiveRun:
    """Run one session of the vehicles ``inputs`` names (id -> (L, 2) z, m/s) through ``relay``.

    Parameters
    ----------
    fleet : SecAggFleet
    inputs : dict of int to (L, 2) array_like
        The vehicles asked to take part (the aggregator's roster choice) and their measurements.
    session : bytes
        ``session_id(segment, epoch)``.
    measured : (int, int), optional
        The (segment, epoch) of the inputs; default that of ``session``.
    relay : Relay, optional
        Honest by default.
    dropped_before_masking, silent_in_unmasking : iterable of int
        Vehicles that vanish after round 1 / do not answer in round 3.
    corrupt : callable, optional
        ``corrupt(reveal) -> reveal`` applied to every reveal (malicious holders).
    rng : None, int or Generator
        Roots of the vehicles' session secrets (reproducible); None: ``os.urandom``.

    Returns
    -------
    ActiveRun
    """
    relay = relay or Relay()
    gen = None if rng is None else np.random.default_rng(rng)
    measured = measured or (int.from_bytes(session[0:8], "little"), int.from_bytes(session[8:16], "little"))
    ids = sorted(inputs)
    veh = {i: fleet.vehicles[i] for i in ids}
    refusals: dict[int, str] = {}
    ms, sent = np.zeros((fleet.n, len(ROUNDS))), np.zeros((fleet.n, len(ROUNDS)), dtype=np.int64)
    def step(i: int, r: int, fn: Callable[..., _T], *args: Any) -> _T | None:
        t0 = time.perf_counter()
        out = _try(refusals, i, fn, *args)
        ms[i - 1, r] += (time.perf_counter() - t0) * 1e3
        return out
    adverts = {i: step(i, 0, lambda v: v.advertise(session, root=None if gen is None else gen.bytes(KEY_NBYTES)),
                       veh[i]) for i in ids}
    signed = {i: a for i, a in adverts.items() if a is not None}
    sent[[i - 1 for i in signed], 0] = [len(a) for a in signed.values()]
    sealed: dict[tuple[int, int], bytes] = {}
    coms: dict[int, bytes] = {}
    for i in ids:
        out = step(i, 1, veh[i].share_keys, relay.roster(i, signed))
        if out is not None:
            sealed.update({(i, j): c for j, c in out[0].items()})
            coms[i] = out[1]
            sent[i - 1, 1] = sum(len(c) + 4 for c in out[0].values()) + len(out[1])
    gone, silent = set(dropped_before_masking), set(silent_in_unmasking)
    masked: dict[int, MaskedInput] = {}
    for i in ids:
        if i in coms and i not in gone:
            m = step(i, 2, veh[i].mask_input, inputs[i], measured)
            if m is not None:
                masked[i] = m
                sent[i - 1, 2] = m.nbytes
    u3 = sorted(masked)
    views: dict[int, bytes] = {}
    for i in u3:
        v = step(i, 3, veh[i].sign_survivors, relay.survivors(i, u3))
        if v is not None:
            views[i] = v
            sent[i - 1, 3] = len(v)
    reveals: list[Reveal] = []
    for i in u3:
        if i in views and i not in silent:
            mine = {d: sealed[(d, i)] for d in coms if (d, i) in sealed}
            r = step(i, 4, veh[i].reveal, mine, coms, relay.signatures(i, views))
            if r is not None:
                reveals.append(r if corrupt is None else corrupt(r))
                sent[i - 1, 4] = r.nbytes
    agg, t0 = None, time.perf_counter()
    if reveals and len(coms) == len(ids):
        roster = verify_roster(signed, fleet.trust, session, fleet.spec)
        agg = _try(refusals, 0, unmask_verified, roster, coms, masked.values(), reveals, fleet.spec, fleet.trust)
    return ActiveRun(agg, refusals, tuple(reveals), masked, ms, sent, (time.perf_counter() - t0) * 1e3)


def active_secure_aggregation_cost(inputs: Sequence[Any], spec: SecAggSpec, *, repeats: int = 3,
                                   dropped: Iterable[int] = (),
                                   rng: int | np.random.Generator | None = None) -> dict[str, Any]:
    """Cost per vehicle and exactness of the active protocol on ``inputs`` (fresh fleet and ledgers per run).

    Parameters
    ----------
    inputs : sequence of (L, 2) array_like
        Vehicle ``i``'s ``z`` is ``inputs[i - 1]``, m/s.
    spec : SecAggSpec
    repeats : int
        Sessions run; times are medians over them.
    dropped : iterable of int
        Vehicles that vanish after round 1 (their masks are removed by reconstruction).
    rng : None, int or Generator
        Session secrets.

    Returns
    -------
    dict
        ``ms_per_message`` (median over sessions of the mean per-vehicle ms over all rounds),
        ``ms_by_round``, ``bytes_per_message`` (bytes a vehicle sends in all rounds, mean),
        ``rounds`` (5), ``aggregator_ms``, ``max_rel_error`` (average against the plain average of the
        clipped inputs of the survivors, relative to its peak).
    """
    repeats = check_int("repeats", repeats, low=1)
    gen = np.random.default_rng(rng)
    zs = {i + 1: np.asarray(z, float) for i, z in enumerate(inputs)}
    gone = set(dropped)
    plain = np.mean([np.clip(z, -spec.clip, spec.clip) for i, z in zs.items() if i not in gone], axis=0)
    runs, aggs = [], []
    for r in range(repeats):
        run = run_active_session(SecAggFleet(len(zs), spec), zs, bytes(8) + r.to_bytes(8, "little"),
                                 dropped_before_masking=gone, rng=gen)
        if run.aggregate is None:
            raise MessageError(f"an honest session was refused: {run.refusals}")
        runs.append(run)
        aggs.append(run.aggregate)
    err = max(float(np.max(np.abs(a.result.average - plain))) for a in aggs) / float(np.max(np.abs(plain)))
    full = [i - 1 for i in zs if i not in gone]     # vehicles that take part in every round
    return {"ms_per_message": float(np.median([r.vehicle_ms[full].sum(axis=1).mean() for r in runs])),
            "ms_by_round": dict(zip(ROUNDS, np.median([r.vehicle_ms.mean(axis=0) for r in runs], axis=0).tolist())),
            "bytes_per_message": int(round(runs[0].bytes_sent[full].sum(axis=1).mean())), "rounds": len(ROUNDS),
            "aggregator_ms": float(np.median([r.aggregator_ms for r in runs])), "max_rel_error": err}
