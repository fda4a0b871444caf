"""The wire of validated, phased sessions between parties (:mod:`.prioround`): topics, framing, keys.

Topics of the session on measurement ``(segment, epoch)``, under ``{prefix}/prio/{segment}/{epoch}``:

- ``.../to/{vid}``: leader -> vehicle, unsigned framing (what it carries is signed by the aggregators):
  ``invite`` (phase, protocol id, roster; the helpers' key adverts; from phase 2 the previous phase's
  result signed by every aggregator) and ``closed``;
- ``.../up/{vid}``: vehicle -> leader, an envelope signed by the vehicle for that topic: its commitments
  (:func:`commitments_blob`), the leader's share in the clear and each helper's share sealed to that
  helper's X25519 key (the leader relays it unread);
- ``.../fwd/{party}``: leader -> helper ``party``: a vehicle's commitments, its certificate and the share
  sealed to ``party``;
- ``.../agg/{party}``: aggregator ``party`` -> the others, envelopes signed by its certified identity:
  ``open`` (roster; the leader), ``commit`` and ``reveal`` (the coin toss of the query randomness),
  ``close`` (the uploads of the phase; the leader), ``vshares`` (verifier shares), ``set`` (the accepted
  set), ``sums`` (component sums), ``result`` (the signed ``m_k``), ``abort``, ``closed`` (the leader).

Each aggregator advertises its X25519 key signed by its identity on ``{prefix}/prio/key/{id}``
(:func:`open_advert`). A framed message is a 4-byte header length, a JSON header (at most
:data:`MAX_HEADER` bytes) naming the lengths of the binary parts, then the parts.
"""

from __future__ import annotations

import hashlib
import json
import struct

import numpy as np

from ..errors import MessageError
from ..privacy.secagg_flp import Field, ValidityEncoding
from ..privacy.secagg_replicated import AggregatorShare, Commitments
from ..privacy.secagg_store import view_digest
from ..wire.certificate import Certificate
from ..wire.envelope import open_envelope
from ..wire.identity import FleetTrust, VehicleIdentity
from .messages import seal
from .relaykey import RelayKey

__all__ = ["MAX_HEADER", "MAX_ID", "PrioTopics", "AggregatorKeys", "pack", "unpack", "key_topic", "open_advert",
           "result_bytes", "elements", "ids_field", "int_field", "commitments_blob", "read_commitments", "share_blob",
           "read_share"]

MAX_HEADER = 64 * 1024
_RESULT = b"roadcollab/prio/result/v2|"


def pack(header: dict, *blobs: bytes) -> bytes:
    """A framed message: ``header`` (JSON) and the binary ``blobs``.

    Parameters
    ----------
    header : dict
        JSON-ready values (its ``blobs`` key is set to the parts' sizes).
    *blobs : bytes
        Binary parts, in order.
    """
    h = json.dumps(dict(header, blobs=[len(b) for b in blobs]), sort_keys=True, separators=(",", ":")).encode()
    return struct.pack("<I", len(h)) + h + b"".join(bytes(b) for b in blobs)


def unpack(data: bytes, what: str) -> tuple[dict, list[bytes]]:
    """``(header, blobs)`` of an untrusted framed message.

    Parameters
    ----------
    data : bytes
        Untrusted.
    what : str
        Named in the error.

    Raises
    ------
    MessageError
        Truncated, a header that is not a JSON object or too long, or parts that do not add up.
    """
    data = bytes(data)
    if len(data) < 4:
        raise MessageError(f"{what}: truncated")
    (n,) = struct.unpack_from("<I", data)
    if n > MAX_HEADER or 4 + n > len(data):
        raise MessageError(f"{what}: header of {n} bytes (at most {MAX_HEADER}, within the message)")
    try:
        h = json.loads(data[4:4 + n].decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as err:     # RecursionError: nested too deep
        raise MessageError(f"{what}: header is not JSON ({type(err).__name__})") from None
    sizes = h.get("blobs") if isinstance(h, dict) else None
    if not isinstance(sizes, list) or not all(isinstance(k, int) and not isinstance(k, bool) and k >= 0
                                              for k in sizes):
        raise MessageError(f"{what}: expected a JSON object with the list of part sizes")
    if 4 + n + sum(sizes) != len(data):
        raise MessageError(f"{what}: the parts' sizes do not add up to the message's length")
    blobs, off = [], 4 + n
    for k in sizes:
        blobs.append(data[off:off + k])
        off += k
    return h, blobs


#: Protocol ids and phases are below this (they travel as 4 bytes).
MAX_ID = 2 ** 31


def int_field(h: dict, key: str, what: str, low: int = 0) -> int:
    """An integer in ``[low, MAX_ID)`` of a header (MessageError otherwise).

    Parameters
    ----------
    h : dict
        Header.
    key : str
    what : str
        Named in the error.
    low : int
    """
    v = h.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not low <= v < MAX_ID:
        raise MessageError(f"{what}: {key!r} must be an integer from {low} to {MAX_ID - 1}, got {str(v)[:40]}")
    return v


def ids_field(h: dict, key: str, what: str) -> tuple[int, ...]:
    """A sorted tuple of distinct positive protocol ids of a header (MessageError otherwise).

    Parameters
    ----------
    h : dict
        Header.
    key : str
    what : str
        Named in the error.
    """
    v = h.get(key)
    if not isinstance(v, list) or not all(isinstance(i, int) and not isinstance(i, bool) and 0 < i < MAX_ID for i in v) \
            or len(set(v)) != len(v):
        raise MessageError(f"{what}: {key!r} must be a list of distinct positive protocol ids")
    return tuple(sorted(v))


def elements(f: Field, blob: bytes, what: str, n: int | None = None) -> np.ndarray:
    """Field elements of an untrusted part (``n`` of them, or as many as it holds).

    Parameters
    ----------
    f : Field
    blob : bytes
    what : str
        Named in the error.
    n : int, optional
    """
    if n is None:
        if len(blob) % f.nbytes:
            raise MessageError(f"{what}: not a whole number of field elements")
        n = len(blob) // f.nbytes
    return f.from_bytes(blob, n, what)


def commitments_blob(c: Commitments) -> bytes:
    """A vehicle's commitments as one part: its joint-randomness parts, its proof digest and its signature.

    Parameters
    ----------
    c : Commitments
    """
    return b"".join(c.parts) + c.proof_digest + c.signature


def read_commitments(blob: bytes, vehicle: int, aggregators: int) -> Commitments:
    """The commitments of :func:`commitments_blob` from an untrusted part.

    Parameters
    ----------
    blob : bytes
    vehicle : int
        The protocol id they belong to.
    aggregators : int

    Raises
    ------
    MessageError
        Not ``aggregators`` 32-byte parts, a 32-byte digest and a 64-byte signature.
    """
    blob = bytes(blob)
    if len(blob) != 32 * aggregators + 32 + 64:
        raise MessageError(f"vehicle {vehicle}: commitments of {len(blob)} bytes, expected {32 * aggregators + 96}")
    parts = tuple(blob[32 * j:32 * (j + 1)] for j in range(aggregators))
    return Commitments(vehicle, parts, blob[32 * aggregators:32 * aggregators + 32], blob[32 * aggregators + 32:])


def share_blob(share: AggregatorShare, f: Field) -> bytes:
    """One aggregator's share of a vehicle's input as one part (component 0 in full, seeds, blinds).

    Parameters
    ----------
    share : AggregatorShare
    f : Field
    """
    blobs = [] if share.x0 is None or share.proof0 is None else [f.to_bytes(share.x0), f.to_bytes(share.proof0)]
    blobs += [share.seeds[j] for j in share.comps if j] + [share.blinds[j] for j in share.comps]
    return pack({"comps": list(share.comps)}, *blobs)


def read_share(blob: bytes, comps: tuple[int, ...], enc: ValidityEncoding, what: str) -> AggregatorShare:
    """An aggregator's share of :func:`share_blob` from an untrusted part.

    Parameters
    ----------
    blob : bytes
    comps : tuple of int
        The components the reading aggregator holds.
    enc : ValidityEncoding
        The phase's.
    what : str
        Named in the error.

    Raises
    ------
    MessageError
        Other components, parts of the wrong size, or elements outside the field.
    """
    h, blobs = unpack(blob, what)
    if h.get("comps") != list(comps):
        raise MessageError(f"{what}: the share of components {h.get('comps')!r}, expected {list(comps)}")
    x0 = proof0 = None
    if 0 in comps:
        if len(blobs) < 2:
            raise MessageError(f"{what}: component 0 missing")
        f = enc.field
        x0 = elements(f, blobs[0], f"{what}: x share", enc.length + enc.n_bits)
        proof0 = elements(f, blobs[1], f"{what}: proof share", enc.proof_length)
        blobs = blobs[2:]
    seeded = [j for j in comps if j]
    if len(blobs) != len(seeded) + len(comps) or any(len(b) != 16 for b in blobs):
        raise MessageError(f"{what}: expected {len(seeded)} seeds and {len(comps)} blinds of 16 bytes")
    return AggregatorShare(tuple(comps), x0, proof0, dict(zip(seeded, blobs)), dict(zip(comps, blobs[len(seeded):])))


class PrioTopics:
    """Topic names of the session on measurement ``(segment, epoch)`` (module docstring).

    Parameters
    ----------
    prefix : str
        ``rc/{fleet_id}`` on the network.
    segment, epoch : int
    """

    def __init__(self, prefix: str, segment: int, epoch: int) -> None:
        self.prefix, self.segment, self.epoch = prefix, int(segment), int(epoch)
        self.base = f"{prefix}/prio/{self.segment}/{self.epoch}"

    def to(self, vid: str) -> str:
        return f"{self.base}/to/{vid}"

    def up(self, vid: str) -> str:
        return f"{self.base}/up/{vid}"

    def agg(self, party: str) -> str:
        """Where aggregator ``party`` publishes its messages to the others.

        Parameters
        ----------
        party : str
        """
        return f"{self.base}/agg/{party}"

    def fwd(self, party: str) -> str:
        """Where the leader forwards the vehicles' sealed shares to helper ``party``.

        Parameters
        ----------
        party : str
        """
        return f"{self.base}/fwd/{party}"

    def sealed_part(self, pid: int, phase: int, party: str) -> str:
        """The associated data of a vehicle's share sealed to ``party`` (not a topic anything is sent on).

        Parameters
        ----------
        pid : int
            Protocol id.
        phase : int
        party : str
            The helper it is sealed to.
        """
        return f"{self.base}/part/{int(pid)}/{int(phase)}/{party}"

    @staticmethod
    def parse(prefix: str, topic: str) -> tuple[int, int, list[str]]:
        """``(segment, epoch, rest)`` of a session topic (MessageError for another topic).

        Parameters
        ----------
        prefix : str
        topic : str
        """
        head = f"{prefix}/prio/"
        parts = topic[len(head):].split("/") if topic.startswith(head) else []
        # ASCII digits only: str.isdigit() also holds for digits int() refuses (superscripts).
        if len(parts) < 3 or not all(p.isascii() and p.isdigit() and len(p) <= 9 for p in parts[:2]):
            raise MessageError(f"{topic}: not a validated-session topic under {head}")
        return int(parts[0]), int(parts[1]), parts[2:]


def key_topic(prefix: str, party: str) -> str:
    """Where aggregator ``party`` advertises its X25519 key.

    Parameters
    ----------
    prefix : str
    party : str
        The aggregator's certificate id.
    """
    return f"{prefix}/prio/key/{party}"


class AggregatorKeys:
    """An aggregator's certified identity (signs) and X25519 key (opens sealed parts, agrees the verify key).

    Parameters
    ----------
    identity : VehicleIdentity
        Its certificate's id is the aggregator's role id (:class:`~.prioround.PrioParams`).
    key : RelayKey
    """

    def __init__(self, identity: VehicleIdentity, key: RelayKey) -> None:
        self.identity, self.key = identity, key

    @property
    def party(self) -> str:
        return self.identity.vehicle_id

    def advert(self, prefix: str) -> bytes:
        """The X25519 public key signed for :func:`key_topic`.

        Parameters
        ----------
        prefix : str
        """
        return seal(self.identity, key_topic(prefix, self.party), self.key.public)


def open_advert(data: bytes, trust: FleetTrust, prefix: str, party: str) -> tuple[Certificate, bytes]:
    """``(certificate, X25519 public key)`` of aggregator ``party``'s advert.

    Parameters
    ----------
    data : bytes
        The advert (untrusted).
    trust : FleetTrust
    prefix : str
    party : str
        The aggregator id it must be signed by.

    Raises
    ------
    MessageError
        Not signed by a certificate of ``party`` the fleet trusts (a key substituted by the other aggregator
        or anyone else), or not a 32-byte key.
    """
    cert, pub = open_envelope(bytes(data), trust, context=key_topic(prefix, party).encode())
    if cert.vehicle_id != party:
        raise MessageError(f"key advert of {party!r} signed by {cert.vehicle_id!r}")
    if len(pub) != 32:
        raise MessageError(f"key advert of {party!r}: expected a 32-byte X25519 key")
    return cert, pub


def result_bytes(session: bytes, phase: int, accepted, m: bytes) -> bytes:
    """What every aggregator signs of a phase's result: session, phase, accepted set and the result's float64 bytes.

    Parameters
    ----------
    session : bytes
    phase : int
    accepted : iterable of int
    m : bytes
        ``m_k`` as little-endian float64.
    """
    return _RESULT + bytes(session) + struct.pack("<I", int(phase)) + view_digest(accepted) + \
        hashlib.sha256(bytes(m)).digest()
