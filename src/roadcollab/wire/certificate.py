"""Vehicle certificates: the fleet authority's Ed25519 signature binding a vehicle id to its key.

See :mod:`roadcollab.wire.identity` for the authority, the trust anchor and the key files; the wire form::

    certificate := "RCCERT1" 0x00 | u16 len fleet_id | fleet_id | u16 len vehicle_id | vehicle_id
                   | 32-byte Ed25519 public key | u64 issued_s | 64-byte authority signature
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from types import ModuleType

from ..errors import MessageError, ParameterError

__all__ = ["CERT_CONTEXT", "Certificate", "check_id", "verify_signature"]

CERT_MAGIC = b"RCCERT1\x00"
CERT_CONTEXT = b"roadcollab/certificate/v1\x00"
_KEY = 32
_SIG = 64
_MAX_ID = 64


def check_id(name: str, value: str) -> str:
    """A fleet or vehicle id: 1-64 characters of ``[A-Za-z0-9_.-]`` (safe in MQTT topics and file names).

    Parameters
    ----------
    name : str
        What the id is, for the message.
    value : str

    Returns
    -------
    str
        ``value``.

    Raises
    ------
    ParameterError
    """
    ok = isinstance(value, str) and 0 < len(value) <= _MAX_ID and all(c.isascii() and (c.isalnum() or c in "_.-")
                                                                          for c in value)
    if not ok or value in (".", ".."):
        raise ParameterError(f"{name} must be 1-{_MAX_ID} characters of letters, digits, '_', '.', '-', got {value!r}")
    return value


def _ed25519() -> ModuleType:
    from cryptography.hazmat.primitives.asymmetric import ed25519
    return ed25519


def verify_signature(public_key: bytes, data: bytes, signature: bytes, what: str) -> None:
    """Check an Ed25519 signature; :class:`~roadcollab.errors.MessageError` naming ``what`` if it fails.

    Parameters
    ----------
    public_key : bytes
        32-byte raw Ed25519 public key.
    data, signature : bytes
        The signed bytes (context included) and the 64-byte signature.
    what : str
        What was signed, for the message.
    """
    from cryptography.exceptions import InvalidSignature

    try:
        _ed25519().Ed25519PublicKey.from_public_bytes(bytes(public_key)).verify(bytes(signature), bytes(data))
    except (InvalidSignature, ValueError):
        raise MessageError(f"{what}: bad signature") from None


def _pack_str(s: str) -> bytes:
    b = s.encode("ascii")
    return struct.pack(">H", len(b)) + b


class _Reader:
    """Bounds-checked reading of untrusted bytes."""

    def __init__(self, data: bytes, what: str):
        self.data, self.pos, self.what = bytes(data), 0, what

    def take(self, n: int) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            raise MessageError(f"{self.what}: truncated (needs {self.pos + n} bytes, got {len(self.data)})")
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def u(self, fmt: str) -> int:
        value: int = struct.unpack(fmt, self.take(struct.calcsize(fmt)))[0]
        return value

    def string(self, name: str) -> str:
        raw = self.take(self.u(">H"))
        try:
            return check_id(f"{self.what} {name}", raw.decode("ascii"))
        except (UnicodeDecodeError, ParameterError) as err:
            raise MessageError(f"{self.what}: bad {name} ({err})") from None

    def end(self) -> None:
        if self.pos != len(self.data):
            raise MessageError(f"{self.what}: {len(self.data) - self.pos} trailing bytes")


@dataclass(frozen=True)
class Certificate:
    """A vehicle's certificate: the fleet authority's signature binding ``vehicle_id`` to ``public_key``.

    Attributes
    ----------
    fleet_id, vehicle_id : str
        Ids (:func:`check_id`).
    public_key : bytes
        The vehicle's 32-byte raw Ed25519 public key.
    issued_s : int
        Issue time, s since the Unix epoch (informative; revocation is by :class:`FleetTrust`).
    signature : bytes
        The authority's 64-byte Ed25519 signature of :meth:`signed_bytes`.
    """

    fleet_id: str
    vehicle_id: str
    public_key: bytes
    issued_s: int
    signature: bytes

    def signed_bytes(self) -> bytes:
        """The bytes the authority signs: :data:`CERT_CONTEXT` and every field but the signature."""
        return (CERT_CONTEXT + _pack_str(self.fleet_id) + _pack_str(self.vehicle_id) + bytes(self.public_key)
                + struct.pack(">Q", self.issued_s))

    def to_bytes(self) -> bytes:
        """The certificate's wire form (module docstring)."""
        return CERT_MAGIC + self.signed_bytes()[len(CERT_CONTEXT):] + bytes(self.signature)

    @classmethod
    def from_bytes(cls, data: bytes) -> "Certificate":
        """Parse a certificate (its signature is *not* checked here: :meth:`FleetTrust.check` does).

        Parameters
        ----------
        data : bytes
            Untrusted wire form.

        Returns
        -------
        Certificate

        Raises
        ------
        MessageError
            Wrong magic, truncated, bad id, trailing bytes.
        """
        r = _Reader(data, "certificate")
        if r.take(len(CERT_MAGIC)) != CERT_MAGIC:
            raise MessageError("certificate: wrong magic")
        fleet, vehicle = r.string("fleet_id"), r.string("vehicle_id")
        pk, issued, sig = r.take(_KEY), r.u(">Q"), r.take(_SIG)
        r.end()
        return cls(fleet, vehicle, pk, issued, sig)


