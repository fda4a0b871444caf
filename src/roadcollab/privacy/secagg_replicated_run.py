"""Replicated validated aggregation (:mod:`.secagg_replicated`): every aggregator's decision from all reports,
the total from all component sums, and every aggregator in-process.

What an aggregator receives from the others is untrusted: a component's two holders must report the same
verifier share and the same sum, and a difference is a deviating aggregator (the caller aborts).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from .._validation import check_int
from ..errors import MessageError, ParameterError
from .secagg_flp import ValidityEncoding, decide
from .secagg_replicated import ReplicatedAggregator, Upload, Verification, coin_key, holdings
from .secagg_validity import ValidatedAggregate

__all__ = ["combine_verifications", "combine_sums", "run_replicated_aggregation"]


def combine_verifications(enc: ValidityEncoding, aggregators: int, vehicles: Iterable[int],
                          reports: Sequence[dict[int, Verification | str]]) -> tuple[tuple[int, ...], dict[int, str],
                                                                                   list[str]]:
    """Every aggregator's decision on every vehicle, from all aggregators' (untrusted) reports.

    Parameters
    ----------
    enc : ValidityEncoding
    aggregators : int
    vehicles : iterable of int
        The vehicles whose uploads were closed.
    reports : sequence of dict
        Per aggregator (in order): vehicle to its :class:`Verification`, or to why it refused the vehicle.

    Returns
    -------
    accepted : tuple of int
    refused : dict
        Vehicle to why (refused by an aggregator, another joint randomness, or a failed proof).
    conflicts : list of str
        Components whose two holders report different verifier shares: an aggregator deviated (the
        caller aborts).
    """
    hold, p = holdings(aggregators), enc.field.p
    accepted, refused, conflicts = [], {}, []
    for i in sorted(set(vehicles)):
        got = [rep.get(i, f"no report of vehicle {i}") for rep in reports]
        why = next((f"aggregator {a} refused it: {g}" for a, g in enumerate(got) if isinstance(g, str)), "")
        if why:
            refused[i] = f"vehicle {i}: {why}"
            continue
        ver = [g for g in got if isinstance(g, Verification)]
        if len({v.joint for v in ver}) != 1:
            refused[i] = f"vehicle {i}: the aggregators' shares give different joint randomness"
            continue
        total, clash = np.zeros(2 * enc.chunk + 3, dtype=object), False
        for j in range(aggregators):
            vals = [np.asarray(ver[a].values.get(j, ()), dtype=object) for a in range(aggregators) if j in hold[a]]
            if any(v.shape != (2 * enc.chunk + 3,) for v in vals) or any(not np.array_equal(vals[0], v) for v in vals):
                conflicts.append(f"vehicle {i}: the holders of component {j} report different verifier shares")
                clash = True
                break
            total = (total + vals[0]) % p
        if clash:
            continue
        why = decide(enc, total)
        if why:
            refused[i] = f"vehicle {i}: {why}"
        else:
            accepted.append(i)
    return tuple(accepted), refused, conflicts


def combine_sums(enc: ValidityEncoding, aggregators: int, sums: Sequence[dict[int, np.ndarray]]) -> np.ndarray:
    """The total of the ``q`` over the accepted set from every aggregator's component sums (untrusted).

    Parameters
    ----------
    enc : ValidityEncoding
    aggregators : int
    sums : sequence of dict
        Per aggregator: component to its sum, (L,) object ndarray.

    Raises
    ------
    MessageError
        The two holders of a component report different sums (an aggregator deviated), or a sum is missing.
    """
    hold, p = holdings(aggregators), enc.field.p
    total = np.zeros(enc.length, dtype=object)
    for j in range(aggregators):
        vals = [np.asarray(sums[a].get(j, ()), dtype=object) for a in range(aggregators) if j in hold[a]]
        if any(v.shape != (enc.length,) for v in vals) or any(not np.array_equal(vals[0], v) for v in vals):
            raise MessageError(f"the holders of component {j} report different sums: an aggregator deviated")
        total = (total + vals[0]) % p
    return total


def run_replicated_aggregation(enc: ValidityEncoding, uploads: dict[int, Upload], session: bytes, *,
                               aggregators: int = 3, min_inputs: int = 2, trust: Any = None,
                               certificates: dict[int, Any] | None = None,
                               rng: Any = None) -> ValidatedAggregate:
    """Every aggregator in-process: receive the uploads, toss the coins, verify, agree, sum and combine.

    Parameters
    ----------
    enc : ValidityEncoding
    uploads : dict
        Vehicle id to its :class:`Upload`; a vehicle without one is not counted.
    session : bytes
    aggregators : int
        2 or 3.
    min_inputs : int
        ``k``: no sum of fewer accepted inputs is revealed.
    trust : FleetTrust, optional
    certificates : dict, optional
        Vehicle id to its certificate (with ``trust``).
    rng : int or numpy.random.Generator, optional
        The aggregators' coins.

    Returns
    -------
    ValidatedAggregate
    """
    gen = np.random.default_rng(rng)
    aggs = [ReplicatedAggregator(enc, a, aggregators) for a in range(aggregators)]
    if len(uploads) > enc.max_fleet():
        raise ParameterError(f"at most {enc.max_fleet()} inputs fit the field, got {len(uploads)}")
    reports: list[dict[int, Verification | str]] = [{} for _ in aggs]
    for i, up in sorted(uploads.items()):
        for a, agg in enumerate(aggs):
            try:
                if up.vehicle != i or len(up.shares) != aggregators:
                    raise MessageError(f"vehicle {i}: an upload of vehicle {up.vehicle} with {len(up.shares)} shares")
                cert = None if certificates is None else certificates[i]
                agg.receive(up.commitments, up.shares[a], session, trust, cert)
            except MessageError as e:
                reports[a][i] = str(e)
    key = coin_key(session, [gen.bytes(32) for _ in aggs])
    for a, agg in enumerate(aggs):
        for i in agg.held:
            reports[a][i] = agg.verify(i, session, key)
    accepted, refused, conflicts = combine_verifications(enc, aggregators, uploads, reports)
    if conflicts:
        raise MessageError("; ".join(conflicts))
    if len(accepted) < check_int("min_inputs", min_inputs, low=1):
        return ValidatedAggregate(None, accepted, refused)
    total = combine_sums(enc, aggregators, [agg.component_sums(accepted, min_inputs) for agg in aggs])
    return ValidatedAggregate(enc.decode_sum(total, len(accepted)), accepted, refused)
