"""Topics and payloads of the networked fleet.

Topics (prefix ``rc/<fleet_id>``; ``<vid>`` a vehicle id such as ``v3``, ``<s>`` a segment index)::

    rc/F/v/<vid>/hello        vehicle -> service   signed: the drive's summary and its segments (JSON)
    rc/F/v/<vid>/seg/<s>      vehicle -> service   signed: its Contribution on segment s (binary)
    rc/F/ack/<vid>            service -> vehicle   JSON: what waits for it, what was accepted or refused
    rc/F/seg/<s>/waiting      service -> all       retained: the last accepted contribution on s, as the
                                                   vehicle signed it (the previous vehicle's message
                                                   waiting at this stretch of road)

Every vehicle message is a :func:`~roadcollab.wire.envelope.seal_envelope` bound to its topic, so it does
not verify on another topic or under another vehicle's certificate. Contribution wire form
(little-endian)::

    "RCSEG1" 0x00 | u32 segment | i64 i0 | u32 n | 3 x (n, 2) float64  (single, inversion, collaborative)

Under secure aggregation a vehicle sends the service only the message for the next vehicle, sealed to
the fleet's relay key (:mod:`roadcollab.network.relaykey`): the service can neither read the inversion
nor the vehicle's own estimates (those stay in the vehicle)::

    "RCSEAL1" 0x00 | u32 segment | sealed("RCREL1" 0x00 | u32 segment | i64 i0 | u32 n | (n, 2) float64 inversion)
"""

from __future__ import annotations

import base64
import json
import struct

import numpy as np

from ..errors import MessageError
from ..wire.certificate import Certificate
from ..wire.envelope import open_envelope, seal_envelope
from ..wire.identity import FleetTrust, VehicleIdentity, check_id
from .engine import ESTIMATES, Contribution
from .plan import RoadPlan

__all__ = ["Topics", "encode_contribution", "decode_contribution", "seal", "open_signed", "open_from", "b64", "unb64",
           "encode_waiting", "decode_waiting", "MAX_JSON", "encode_sealed_relay", "sealed_segment", "open_sealed_relay"]

CONTRIB_MAGIC = b"RCSEG1\x00"
SEALED_MAGIC = b"RCSEAL1\x00"
RELAY_MAGIC = b"RCREL1\x00"
_HEAD = struct.Struct("<IqI")
#: The largest JSON payload accepted (hello, ack), bytes.
MAX_JSON = 64 * 1024


class Topics:
    """Topic names of one fleet.

    Parameters
    ----------
    fleet_id : str
    """

    def __init__(self, fleet_id: str) -> None:
        self.fleet_id = check_id("fleet_id", fleet_id)
        self.root = f"rc/{fleet_id}"

    def hello(self, vid: str) -> str:
        return f"{self.root}/v/{vid}/hello"

    def segment(self, vid: str, s: int) -> str:
        return f"{self.root}/v/{vid}/seg/{s}"

    def ack(self, vid: str) -> str:
        return f"{self.root}/ack/{vid}"

    def waiting(self, s: int) -> str:
        return f"{self.root}/seg/{s}/waiting"

    @property
    def from_vehicles(self) -> str:
        """Filter of every vehicle topic (the service's subscription)."""
        return f"{self.root}/v/+/#"

    @property
    def all_waiting(self) -> str:
        return f"{self.root}/seg/+/waiting"

    def parse_vehicle(self, topic: str) -> tuple[str, str, int | None]:
        """``(vid, kind, segment)`` of a vehicle topic (kind ``hello`` or ``seg``).

        Parameters
        ----------
        topic : str
            A received topic.

        Raises
        ------
        MessageError
            Not a vehicle topic of this fleet.
        """
        parts = topic.split("/")
        if len(parts) < 4 or "/".join(parts[:2]) != self.root or parts[2] != "v":
            raise MessageError(f"topic {topic!r}: not a vehicle topic of fleet {self.fleet_id}")
        vid = parts[3]
        if len(parts) == 5 and parts[4] == "hello":
            return vid, "hello", None
        if len(parts) == 6 and parts[4] == "seg" and parts[5].isascii() and parts[5].isdigit() and len(parts[5]) <= 9:
            return vid, "seg", int(parts[5])
        raise MessageError(f"topic {topic!r}: expected .../v/<vid>/hello or .../v/<vid>/seg/<n>")


def encode_contribution(c: Contribution) -> bytes:
    """The wire form of a contribution (module docstring).

    Parameters
    ----------
    c : Contribution
    """
    arrays = b"".join(np.ascontiguousarray(getattr(c, k), dtype="<f8").tobytes() for k in ESTIMATES)
    return CONTRIB_MAGIC + _HEAD.pack(c.segment, c.i0, c.n) + arrays


def decode_contribution(data: bytes, plan: RoadPlan, segment: int) -> Contribution:
    """A contribution from its wire form, checked against the plan and the topic's segment.

    Parameters
    ----------
    data : bytes
        Wire form.
    plan : RoadPlan
        The fleet's plan.
    segment : int
        The topic's segment.

    Raises
    ------
    MessageError
        Wrong magic or length, another segment than the topic's, grid points outside the segment,
        or a value that is not finite.
    """
    data = bytes(data)
    if not data.startswith(CONTRIB_MAGIC) or len(data) < len(CONTRIB_MAGIC) + _HEAD.size:
        raise MessageError("contribution: expected the RCSEG1 header")
    s, i0, n = _HEAD.unpack_from(data, len(CONTRIB_MAGIC))
    body = data[len(CONTRIB_MAGIC) + _HEAD.size:]
    if s != segment:
        raise MessageError(f"contribution: for segment {s} on the topic of segment {segment}")
    a, b = plan.segment_range(s)
    if n < 1 or i0 < a or i0 + n > b:
        raise MessageError(f"contribution: grid points {i0}..{i0 + n - 1} outside segment {s} ({a}..{b - 1})")
    if len(body) != 3 * n * 2 * 8:
        raise MessageError(f"contribution: expected {3 * n * 16} bytes of values for {n} points, got {len(body)}")
    arr = np.frombuffer(body, dtype="<f8").reshape(3, n, 2).astype(float)
    if not np.all(np.isfinite(arr)):
        raise MessageError("contribution: values must be finite")
    if np.max(np.abs(arr)) > 10.0:
        raise MessageError("contribution: an elevation above 10 m is not a road")
    return Contribution(s, int(i0), arr[0], arr[1], arr[2])


def encode_sealed_relay(c: Contribution, relay_key, topic: str) -> bytes:
    """The secure-aggregation contribution body: ``c``'s inversion sealed to the fleet (module docstring).

    Parameters
    ----------
    c : Contribution
    relay_key : RelayKey
    topic : str
        The contribution's topic (bound into the seal).
    """
    inner = RELAY_MAGIC + _HEAD.pack(c.segment, c.i0, c.n) + np.ascontiguousarray(c.inversion, dtype="<f8").tobytes()
    return SEALED_MAGIC + struct.pack("<I", c.segment) + relay_key.seal(topic, inner)


def sealed_segment(data: bytes, segment: int) -> None:
    """Check what the service can of a sealed contribution: its header and the topic's segment.

    Parameters
    ----------
    data : bytes
    segment : int

    Raises
    ------
    MessageError
    """
    data = bytes(data)
    if not data.startswith(SEALED_MAGIC) or len(data) < len(SEALED_MAGIC) + 4 + 48:
        raise MessageError("contribution: expected the RCSEAL1 header of a sealed relay message (the fleet "
                           "aggregates securely)")
    (s,) = struct.unpack_from("<I", data, len(SEALED_MAGIC))
    if s != segment:
        raise MessageError(f"contribution: for segment {s} on the topic of segment {segment}")
    if len(data) > 64 * 2 ** 20:
        raise MessageError("contribution: larger than 64 MiB")


def open_sealed_relay(data: bytes, relay_key, topic: str, plan: RoadPlan, segment: int) -> Contribution:
    """The relayed inversion of a sealed contribution (a vehicle's side), checked as
    :func:`decode_contribution` checks a clear one.

    Parameters
    ----------
    data : bytes
    relay_key : RelayKey
    topic : str
        The topic it was published on.
    plan : RoadPlan
    segment : int

    Returns
    -------
    Contribution
        Only ``inversion`` is sent; ``single`` and ``collaborative`` are that same array (a receiver
        uses the inversion alone).

    Raises
    ------
    MessageError
    """
    sealed_segment(data, segment)
    inner = relay_key.open(topic, bytes(data)[len(SEALED_MAGIC) + 4:])
    if not inner.startswith(RELAY_MAGIC) or len(inner) < len(RELAY_MAGIC) + _HEAD.size:
        raise MessageError("relay message: expected the RCREL1 header")
    s, i0, n = _HEAD.unpack_from(inner, len(RELAY_MAGIC))
    body = inner[len(RELAY_MAGIC) + _HEAD.size:]
    a, b = plan.segment_range(segment)
    if s != segment or n < 1 or i0 < a or i0 + n > b or len(body) != n * 16:
        raise MessageError(f"relay message: grid points {i0}..{i0 + n - 1} of segment {s} do not fit segment "
                           f"{segment} ({a}..{b - 1}) or the length")
    arr = np.frombuffer(body, dtype="<f8").reshape(n, 2).astype(float)
    if not np.all(np.isfinite(arr)) or np.max(np.abs(arr)) > 10.0:
        raise MessageError("relay message: values must be finite elevations below 10 m")
    return Contribution(s, int(i0), arr, arr, arr)


def seal(identity: VehicleIdentity, topic: str, payload: bytes) -> bytes:
    """``payload`` signed by the vehicle, bound to ``topic``.

    Parameters
    ----------
    identity : VehicleIdentity
        The sender.
    topic : str
        Bound into the signature.
    payload : bytes
    """
    return seal_envelope(identity, payload, context=topic.encode())


def open_signed(data: bytes, trust: FleetTrust, topic: str, vid: str) -> tuple[Certificate, bytes]:
    """``(certificate, payload)`` of an envelope published on ``topic`` by party ``vid`` (see :func:`open_from`).

    Parameters
    ----------
    data : bytes
        The envelope.
    trust : FleetTrust
    topic : str
        Where it was published (bound into the signature).
    vid : str
        The certificate id it must be signed by.

    Raises
    ------
    MessageError
        As :func:`open_from`.
    """
    cert, payload = open_envelope(bytes(data), trust, context=topic.encode())
    if cert.vehicle_id != vid:
        raise MessageError(f"topic {topic!r}: signed by {cert.vehicle_id}, not by {vid}")
    return cert, payload


def open_from(data: bytes, trust: FleetTrust, topic: str, vid: str) -> bytes:
    """The payload of an envelope published on ``topic`` by vehicle ``vid``.

    Parameters
    ----------
    data : bytes
        The envelope.
    trust : FleetTrust
        Trust anchor.
    topic : str
        Where it was published.
    vid : str
        The topic's vehicle id.

    Raises
    ------
    MessageError
        Not an envelope, a bad signature (e.g. replayed from another topic), a certificate the fleet
        does not trust, or a certificate of another vehicle than the topic's.
    """
    return open_signed(data, trust, topic, vid)[1]


def encode_waiting(vid: str, envelope: bytes) -> bytes:
    """A retained waiting message: the sender's id and its envelope as it signed it.

    Parameters
    ----------
    vid : str
        Sender.
    envelope : bytes
        As it signed it.
    """
    v = vid.encode()
    return struct.pack("<B", len(v)) + v + bytes(envelope)


def decode_waiting(data: bytes) -> tuple[str, bytes]:
    """``(vid, envelope)`` of a waiting message.

    Parameters
    ----------
    data : bytes

    Raises
    ------
    MessageError
    """
    data = bytes(data)
    if not data or len(data) < 1 + data[0]:
        raise MessageError("waiting message: truncated")
    try:
        vid = check_id("vehicle id", data[1:1 + data[0]].decode())
    except (UnicodeDecodeError, ValueError) as err:
        raise MessageError(f"waiting message: bad vehicle id ({err})") from None
    return vid, data[1 + data[0]:]


def b64(data: bytes) -> str:
    """``data`` as base64 text (a JSON field).

    Parameters
    ----------
    data : bytes
    """
    return base64.b64encode(bytes(data)).decode()


def unb64(text, what: str) -> bytes:
    """The bytes of an untrusted base64 field (at most 4 MiB of text).

    Parameters
    ----------
    text : str
    what : str
        Named in the error.

    Raises
    ------
    MessageError
        Not a string, too long, or not base64.
    """
    if not isinstance(text, str) or len(text) > 4 * 2 ** 20:
        raise MessageError(f"{what}: expected a base64 string")
    try:
        return base64.b64decode(text.encode(), validate=True)
    except ValueError:
        raise MessageError(f"{what}: not base64") from None


def encode_json(obj: dict) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()


def decode_json(data: bytes, what: str) -> dict:
    """A JSON object of at most :data:`MAX_JSON` bytes.

    Raises
    ------
    MessageError
    """
    if len(data) > MAX_JSON:
        raise MessageError(f"{what}: larger than {MAX_JSON} bytes")
    try:
        obj = json.loads(bytes(data).decode())
    except (UnicodeDecodeError, ValueError) as err:
        raise MessageError(f"{what}: not JSON ({err})") from None
    if not isinstance(obj, dict):
        raise MessageError(f"{what}: expected a JSON object")
    return obj
