"""Public parameters of validated, phased sessions (:mod:`.prioround`) and the results every aggregator signs.

:class:`PrioParams` is the same for every party; :func:`result_bundle` is a phase's result with every
aggregator's signature, as the leader relays it to the vehicles, and :func:`open_result` the vehicles' check
of it; :func:`closed_notices` the leader's notices of a session's end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import check_int
from ..errors import MessageError, ParameterError
from ..privacy.secagg_flp import ValidityEncoding
from ..privacy.secagg_phased import check_encodings
from ..wire.certificate import Certificate, check_id, verify_signature
from ..wire.identity import FleetTrust
from .messages import seal
from .priowire import AggregatorKeys, PrioTopics, ids_field, int_field, pack, result_bytes, unpack
from .service import Publish

__all__ = ["PrioParams", "result_bundle", "open_result", "closed_notices", "MAX_EVENTS"]

#: Events a session keeps (the first ones; a deviating party can send any number of refused messages).
MAX_EVENTS = 200


@dataclass(frozen=True)
class PrioParams:
    """Public parameters of a phased session, the same for every party.

    Attributes
    ----------
    wide : ValidityEncoding
        Phase 1's box.
    tight : tuple of ValidityEncoding
        Phases ``2..K`` (each with a norm bound; :func:`~roadcollab.privacy.secagg_phased.radius_schedule`).
    min_inputs : int
        ``k``: no sum over fewer accepted vehicles is released.
    leader_id : str
        Certificate id of the leader (the fleet authority issues it to no vehicle).
    helper_ids : tuple of str
        Certificate ids of the helpers: two (three aggregators, one of which may deviate) or one (two
        aggregators: privacy of the later phases needs both to follow the protocol).
    """

    wide: ValidityEncoding
    tight: tuple[ValidityEncoding, ...] = ()
    min_inputs: int = 2
    leader_id: str = "aggregator-a"
    helper_ids: tuple[str, ...] = ("aggregator-b", "aggregator-c")

    def __post_init__(self) -> None:
        object.__setattr__(self, "tight", tuple(check_encodings(self.wide, list(self.tight), 1 + len(self.tight))))
        check_int("min_inputs", self.min_inputs, low=1)
        object.__setattr__(self, "helper_ids", tuple(self.helper_ids))
        for name in self.aggregators:
            check_id("aggregator id", name)
        if len(self.helper_ids) not in (1, 2):
            raise ParameterError(f"helper_ids: one or two helpers, got {len(self.helper_ids)}")
        if len(set(self.aggregators)) != len(self.aggregators):
            raise ParameterError(f"the aggregator ids must differ, got {list(self.aggregators)}")

    @property
    def aggregators(self) -> tuple[str, ...]:
        """Every aggregator's id, the leader first (the order of the components, :func:`holdings`)."""
        return (self.leader_id, *self.helper_ids)

    @property
    def phases(self) -> int:
        """``K``."""
        return 1 + len(self.tight)

    def encoding(self, phase: int) -> ValidityEncoding:
        """The encoding of ``phase`` (MessageError outside ``1..K``).

        Parameters
        ----------
        phase : int
            1-based.
        """
        if not 1 <= phase <= self.phases:
            raise MessageError(f"phase {phase} is not in 1..{self.phases}")
        return self.wide if phase == 1 else self.tight[phase - 2]


def result_bundle(phase: int, accepted, m: bytes, signatures: list[bytes]) -> bytes:
    """A phase's result as the leader relays it to the vehicles: every aggregator's signature, in order.

    Parameters
    ----------
    phase : int
    accepted : sequence of int
    m : bytes
        ``m_k`` as little-endian float64.
    signatures : list of bytes
    """
    return pack({"phase": phase, "accepted": list(accepted)}, m, *signatures)


def open_result(bundle: bytes, trust: FleetTrust, params: PrioParams, session: bytes, phase: int,
                certificates: dict[str, Certificate]) -> tuple[tuple[int, ...], np.ndarray]:
    """``(accepted, m)`` of a relayed result, checked against every aggregator's signature (MessageError).

    Parameters
    ----------
    bundle : bytes
        From :func:`result_bundle` (untrusted).
    trust : FleetTrust
    params : PrioParams
    session : bytes
        The measurement's ``session_id``.
    phase : int
        The phase it must be the result of.
    certificates : dict
        Every aggregator's id to its certificate (from the checked key adverts).
    """
    h, blobs = unpack(bundle, "previous result")
    acc = ids_field(h, "accepted", "previous result")
    if int_field(h, "phase", "previous result", 1) != phase or len(blobs) != 1 + len(params.aggregators):
        raise MessageError(f"the previous result is not phase {phase}'s with {len(params.aggregators)} signatures")
    for party, sig in zip(params.aggregators, blobs[1:]):
        cert = certificates.get(party)
        if cert is None or cert.vehicle_id != party:
            raise MessageError(f"no certificate of aggregator {party!r}")
        verify_signature(trust.check(cert).public_key, result_bytes(session, phase, acc, blobs[0]), sig,
                         f"{party}'s result")
    return acc, np.frombuffer(blobs[0], dtype="<f8")


def closed_notices(topics: PrioTopics, keys: AggregatorKeys, roster: list[str], outcome: str, reason: str,
                   accepted=(), phase: int = 1) -> list[Publish]:
    """The leader's ``closed`` notices of a session: to the helpers (signed) and to every vehicle of ``roster``.

    Parameters
    ----------
    topics : PrioTopics
    keys : AggregatorKeys
        The leader's.
    roster : list of str
    outcome, reason : str
    accepted : sequence of int
        Phase 1's accepted set.
    phase : int
        The phase it closed in.
    """
    head = {"t": "closed", "outcome": outcome, "reason": reason, "accepted": list(accepted)}
    topic = topics.agg(keys.party)
    return [Publish(topic, seal(keys.identity, topic, pack(dict(head, phase=phase))))] + \
        [Publish(topics.to(v), pack(head)) for v in roster]
